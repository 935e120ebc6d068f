//! The hub's direct listener and who may reach it (issue 36, item 7).
//!
//! The front door's relay ([`crate::relay`]) put a second TCP hop and two more thread wake-ups
//! on every message of a joined host. So the hub's Zenoh session also listens on a port of its
//! own (the **direct** port, on the `--listen` address), and the kernel drops every TCP segment
//! to it — the SYN first — whose source has not proved the run's join secret to the front door:
//! a classic BPF socket filter on Zenoh's listening socket ([`program`]) keeps only the
//! admitted sources (an IPv4 address, or an IPv6 /64, as the door counts them:
//! [`crate::door::source_of`]). A host that proved the secret ([`crate::probe`]) is told the
//! port and opens its session there: Zenoh's own connection, no relay. A host that did not
//! never completes a TCP handshake with it, so Zenoh never reads a byte of it.
//!
//! Zenoh opens the listening socket itself and has no way to take one; the filter is attached
//! to it from outside: [`AdmitList::on`] finds the one socket of this process listening on the
//! direct address (the kernel lets only one bind it) among its open file descriptors, keeps a
//! duplicate of it (so the descriptor it updates is never another socket's), and attaches a
//! filter that admits nobody, right after Zenoh opened it and before anyone was told the port.
//! A socket filter needs no privilege. Accepted connections inherit the filter of the moment
//! they were accepted, which holds their own source.

use std::io;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};

use crate::door::source_of;

// classic BPF opcodes (linux/bpf_common.h: class | size | mode, or class | op | source)
/// `BPF_LD | BPF_W | BPF_ABS`
const LD_W_ABS: u16 = 0x20;
/// `BPF_LD | BPF_B | BPF_ABS`
const LD_B_ABS: u16 = 0x30;
/// `BPF_ALU | BPF_RSH | BPF_K`
const ALU_RSH_K: u16 = 0x74;
/// `BPF_JMP | BPF_JA`
const JMP_JA: u16 = 0x05;
/// `BPF_JMP | BPF_JEQ | BPF_K`
const JMP_JEQ_K: u16 = 0x15;
/// `BPF_RET | BPF_K`
const RET_K: u16 = 0x06;
/// Loads at this offset and past it read the packet's network (IP) header.
const NET: u32 = libc::SKF_NET_OFF as u32;
/// What a filter returns to keep a whole segment (and 0 to drop it).
const KEEP: u32 = u32::MAX;
/// The kernel's limit on a classic BPF program's length (`BPF_MAXINSNS`).
pub const MAX_INSTRUCTIONS: usize = 4096;

fn op(code: u16, jt: u8, jf: u8, k: u32) -> libc::sock_filter {
    libc::sock_filter { code, jt, jf, k }
}

/// Instructions an admitted source takes in [`program`].
fn cost(source: IpAddr) -> usize {
    match source {
        IpAddr::V4(_) => 2,
        IpAddr::V6(_) => 5,
    }
}

/// The filter that keeps the segments whose source address is one of `sources` (each an IPv4
/// address or an IPv6 /64 prefix, as [`source_of`] gives them) and drops every other one.
///
/// It reads the IP version from the network header, then compares the IPv4 source address
/// (bytes 12–15) with each IPv4 source, or the first 8 bytes of the IPv6 source address
/// (bytes 8–15) with each IPv6 prefix. Every comparison jumps by at most one instruction, and
/// the two blocks are reached by `ja`, whose offset has 32 bits: no length limit but the
/// kernel's.
pub fn program(sources: &[IpAddr]) -> Vec<libc::sock_filter> {
    let v4: Vec<u32> = sources
        .iter()
        .filter_map(|s| match s {
            IpAddr::V4(a) => Some(u32::from(*a)),
            IpAddr::V6(_) => None,
        })
        .collect();
    let v6: Vec<(u32, u32)> = sources
        .iter()
        .filter_map(|s| match s {
            IpAddr::V6(a) => {
                let o = a.octets();
                let word = |i: usize| u32::from_be_bytes([o[i], o[i + 1], o[i + 2], o[i + 3]]);
                Some((word(0), word(4)))
            }
            IpAddr::V4(_) => None,
        })
        .collect();
    // the header: 0 ld version; 1 >> 4; 2 == 4 ? 3 : 4; 3 ja V4; 4 == 6 ? 5 : 6; 5 ja V6; 6 drop
    let v4_start = 7u32;
    let v4_len = 1 + 2 * v4.len() as u32 + 1;
    let v6_start = v4_start + v4_len;
    let mut p = vec![
        op(LD_B_ABS, 0, 0, NET),
        op(ALU_RSH_K, 0, 0, 4),
        op(JMP_JEQ_K, 0, 1, 4),
        op(JMP_JA, 0, 0, v4_start - 4),
        op(JMP_JEQ_K, 0, 1, 6),
        op(JMP_JA, 0, 0, v6_start - 6),
        op(RET_K, 0, 0, 0),
    ];
    p.push(op(LD_W_ABS, 0, 0, NET + 12));
    for a in v4 {
        p.push(op(JMP_JEQ_K, 0, 1, a));
        p.push(op(RET_K, 0, 0, KEEP));
    }
    p.push(op(RET_K, 0, 0, 0));
    for (hi, lo) in v6 {
        p.push(op(LD_W_ABS, 0, 0, NET + 8));
        p.push(op(JMP_JEQ_K, 0, 3, hi));
        p.push(op(LD_W_ABS, 0, 0, NET + 12));
        p.push(op(JMP_JEQ_K, 0, 1, lo));
        p.push(op(RET_K, 0, 0, KEEP));
    }
    p.push(op(RET_K, 0, 0, 0));
    p
}

fn attach(fd: RawFd, program: &[libc::sock_filter]) -> io::Result<()> {
    let fprog = libc::sock_fprog {
        len: program.len() as libc::c_ushort,
        filter: program.as_ptr() as *mut libc::sock_filter,
    };
    // SAFETY: `fprog` points at `program`, alive for the call; the kernel copies it
    let r = unsafe {
        libc::setsockopt(
            fd,
            libc::SOL_SOCKET,
            libc::SO_ATTACH_FILTER,
            (&fprog as *const libc::sock_fprog).cast(),
            size_of::<libc::sock_fprog>() as libc::socklen_t,
        )
    };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// The local address `fd` is bound to, if it is a listening TCP socket.
fn listening_at(fd: RawFd) -> Option<SocketAddr> {
    let int_opt = |name| {
        let mut v: libc::c_int = 0;
        let mut len = size_of::<libc::c_int>() as libc::socklen_t;
        // SAFETY: a c_int out-parameter of the size given; a bad fd is an error, not UB
        let r = unsafe {
            libc::getsockopt(
                fd,
                libc::SOL_SOCKET,
                name,
                (&mut v as *mut libc::c_int).cast(),
                &mut len,
            )
        };
        (r == 0).then_some(v)
    };
    if int_opt(libc::SO_ACCEPTCONN)? != 1 || int_opt(libc::SO_TYPE)? != libc::SOCK_STREAM {
        return None;
    }
    // SAFETY: sockaddr_storage is plain old data; zero is a valid value
    let mut ss: libc::sockaddr_storage = unsafe { std::mem::zeroed() };
    let mut len = size_of::<libc::sockaddr_storage>() as libc::socklen_t;
    // SAFETY: an out-buffer of the size given
    if unsafe {
        libc::getsockname(
            fd,
            (&mut ss as *mut libc::sockaddr_storage).cast(),
            &mut len,
        )
    } != 0
    {
        return None;
    }
    match libc::c_int::from(ss.ss_family) {
        libc::AF_INET => {
            // SAFETY: the family says the storage holds a sockaddr_in
            let a: libc::sockaddr_in =
                unsafe { std::ptr::read((&ss as *const libc::sockaddr_storage).cast()) };
            let ip = Ipv4Addr::from(u32::from_be(a.sin_addr.s_addr));
            Some(SocketAddr::new(IpAddr::V4(ip), u16::from_be(a.sin_port)))
        }
        libc::AF_INET6 => {
            // SAFETY: the family says the storage holds a sockaddr_in6
            let a: libc::sockaddr_in6 =
                unsafe { std::ptr::read((&ss as *const libc::sockaddr_storage).cast()) };
            let ip = Ipv6Addr::from(a.sin6_addr.s6_addr);
            Some(SocketAddr::new(IpAddr::V6(ip), u16::from_be(a.sin6_port)))
        }
        _ => None,
    }
}

/// The one socket of this process listening on `at`, duplicated (close-on-exec).
fn find_listener(at: SocketAddr) -> io::Result<OwnedFd> {
    for entry in std::fs::read_dir("/proc/self/fd")? {
        let Some(fd) = entry?
            .file_name()
            .to_str()
            .and_then(|n| n.parse::<RawFd>().ok())
        else {
            continue;
        };
        if listening_at(fd) != Some(at) {
            continue;
        }
        // SAFETY: duplicating a descriptor; the copy is ours alone
        let copy = unsafe { libc::fcntl(fd, libc::F_DUPFD_CLOEXEC, 0) };
        if copy < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `copy` is a fresh descriptor nothing else owns
        let owned = unsafe { OwnedFd::from_raw_fd(copy) };
        // the descriptor may have been closed and reused between the look and the copy
        if listening_at(owned.as_raw_fd()) == Some(at) {
            return Ok(owned);
        }
    }
    Err(io::Error::new(
        io::ErrorKind::NotFound,
        format!("no socket of this process listens on {at}"),
    ))
}

/// The sources admitted to the direct listener, and the filter that says so to the kernel.
#[derive(Debug)]
pub struct AdmitList {
    at: SocketAddr,
    listener: OwnedFd,
    sources: Vec<IpAddr>,
    instructions: usize,
}

impl AdmitList {
    /// Takes hold of this process's socket listening on `at` (Zenoh's) and lets nobody reach
    /// it; an error if there is none or the filter cannot be attached (then the caller must
    /// not tell anyone the port).
    pub fn on(at: SocketAddr) -> io::Result<AdmitList> {
        let listener = find_listener(at)?;
        let p = program(&[]);
        attach(listener.as_raw_fd(), &p)?;
        Ok(AdmitList {
            at,
            listener,
            sources: Vec::new(),
            instructions: p.len(),
        })
    }

    /// The direct listener's address.
    pub fn address(&self) -> SocketAddr {
        self.at
    }

    /// Sources admitted so far.
    pub fn admitted(&self) -> usize {
        self.sources.len()
    }

    /// Admits `src`'s source (its IPv4 address, or its IPv6 /64): true once its connections
    /// reach the direct listener (already admitted included); false if the filter is full
    /// (the kernel's limit on its length) or could not be attached: that host goes through
    /// the relay.
    pub fn admit(&mut self, src: IpAddr) -> bool {
        let source = source_of(src);
        if self.sources.contains(&source) {
            return true;
        }
        if self.instructions + cost(source) > MAX_INSTRUCTIONS {
            return false;
        }
        self.sources.push(source);
        let p = program(&self.sources);
        match attach(self.listener.as_raw_fd(), &p) {
            Ok(()) => {
                self.instructions = p.len();
                true
            }
            Err(_) => {
                self.sources.pop();
                false
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};
    use std::net::{TcpListener, TcpStream};
    use std::time::Duration;

    /// Runs `program` over an IP header the way the kernel does for the loads it uses.
    fn run(program: &[libc::sock_filter], header: &[u8]) -> u32 {
        let (mut a, mut pc) = (0u32, 0usize);
        loop {
            let i = program[pc];
            let at = |k: u32| (k - NET) as usize;
            match i.code {
                LD_B_ABS => a = u32::from(header[at(i.k)]),
                LD_W_ABS => {
                    let o = at(i.k);
                    a = u32::from_be_bytes([header[o], header[o + 1], header[o + 2], header[o + 3]])
                }
                ALU_RSH_K => a >>= i.k,
                JMP_JA => pc += i.k as usize,
                JMP_JEQ_K => pc += usize::from(if a == i.k { i.jt } else { i.jf }),
                RET_K => return i.k,
                c => panic!("opcode {c:#x}"),
            }
            pc += 1;
        }
    }

    fn v4_header(src: Ipv4Addr) -> Vec<u8> {
        let mut h = vec![0u8; 20];
        h[0] = 0x45;
        h[12..16].copy_from_slice(&src.octets());
        h
    }

    fn v6_header(src: Ipv6Addr) -> Vec<u8> {
        let mut h = vec![0u8; 40];
        h[0] = 0x60;
        h[8..24].copy_from_slice(&src.octets());
        h
    }

    #[test]
    fn the_program_keeps_admitted_sources_only_ipv6_by_its_slash_64() {
        let a: IpAddr = "10.77.0.2".parse().unwrap();
        let six: Ipv6Addr = "2001:db8:1:2::9".parse().unwrap();
        let p = program(&[a, source_of(IpAddr::V6(six))]);
        assert_eq!(run(&p, &v4_header("10.77.0.2".parse().unwrap())), KEEP);
        assert_eq!(run(&p, &v4_header("10.77.0.3".parse().unwrap())), 0);
        assert_eq!(run(&p, &v6_header(six)), KEEP);
        assert_eq!(
            run(&p, &v6_header("2001:db8:1:2:ffff::1".parse().unwrap())),
            KEEP
        );
        assert_eq!(run(&p, &v6_header("2001:db8:1:3::9".parse().unwrap())), 0);
        // nobody admitted: everything dropped, whatever the version
        let none = program(&[]);
        assert_eq!(run(&none, &v4_header(Ipv4Addr::LOCALHOST)), 0);
        assert_eq!(run(&none, &v6_header(Ipv6Addr::LOCALHOST)), 0);
        let mut odd = v4_header(Ipv4Addr::LOCALHOST);
        odd[0] = 0x55;
        assert_eq!(run(&p, &odd), 0);
    }

    #[test]
    fn a_long_list_still_fits_the_jumps_and_the_kernel_limit_is_kept() {
        let many: Vec<IpAddr> = (0..1000u32)
            .map(|n| IpAddr::V4(Ipv4Addr::from(0x0a00_0000 + n)))
            .chain((0..300u16).map(|n| IpAddr::V6(Ipv6Addr::new(0xfd00, n, 0, 0, 0, 0, 0, 0))))
            .collect();
        let p = program(&many);
        assert!(p.len() <= MAX_INSTRUCTIONS);
        assert_eq!(run(&p, &v4_header(Ipv4Addr::from(0x0a00_0000 + 999))), KEEP);
        assert_eq!(run(&p, &v4_header(Ipv4Addr::from(0x0a00_0000 + 1000))), 0);
        assert_eq!(
            run(&p, &v6_header(Ipv6Addr::new(0xfd00, 299, 0, 0, 0, 0, 0, 1))),
            KEEP
        );
        assert_eq!(
            run(&p, &v6_header(Ipv6Addr::new(0xfd00, 300, 0, 0, 0, 0, 0, 1))),
            0
        );
    }

    fn dial(from: &str, to: SocketAddr) -> io::Result<TcpStream> {
        // SAFETY: socket(2) has no preconditions
        let s = unsafe { libc::socket(libc::AF_INET, libc::SOCK_STREAM | libc::SOCK_CLOEXEC, 0) };
        assert!(s >= 0);
        // SAFETY: a fresh socket we own
        let fd = unsafe { OwnedFd::from_raw_fd(s) };
        let bind = SocketAddr::new(from.parse().unwrap(), 0);
        let SocketAddr::V4(b) = bind else { panic!() };
        let sin = libc::sockaddr_in {
            sin_family: libc::AF_INET as libc::sa_family_t,
            sin_port: 0,
            sin_addr: libc::in_addr {
                s_addr: u32::from(*b.ip()).to_be(),
            },
            sin_zero: [0; 8],
        };
        // SAFETY: a sockaddr_in of its size
        let r = unsafe {
            libc::bind(
                fd.as_raw_fd(),
                (&sin as *const libc::sockaddr_in).cast(),
                size_of::<libc::sockaddr_in>() as libc::socklen_t,
            )
        };
        assert_eq!(r, 0, "{}", io::Error::last_os_error());
        let stream = TcpStream::from(fd);
        // a blocking connect would wait out the SYN retries: a non-blocking one, then a look
        stream.set_nonblocking(true)?;
        let SocketAddr::V4(t) = to else { panic!() };
        let sin = libc::sockaddr_in {
            sin_family: libc::AF_INET as libc::sa_family_t,
            sin_port: t.port().to_be(),
            sin_addr: libc::in_addr {
                s_addr: u32::from(*t.ip()).to_be(),
            },
            sin_zero: [0; 8],
        };
        // SAFETY: a sockaddr_in of its size (the answer is looked at below, by poll)
        unsafe {
            libc::connect(
                stream.as_raw_fd(),
                (&sin as *const libc::sockaddr_in).cast(),
                size_of::<libc::sockaddr_in>() as libc::socklen_t,
            )
        };
        let mut pfd = libc::pollfd {
            fd: stream.as_raw_fd(),
            events: libc::POLLOUT,
            revents: 0,
        };
        // SAFETY: one pollfd
        let n = unsafe { libc::poll(&mut pfd, 1, 300) };
        if n == 1 && stream.peer_addr().is_ok() {
            stream.set_nonblocking(false)?;
            Ok(stream)
        } else {
            Err(io::Error::new(io::ErrorKind::TimedOut, "no answer"))
        }
    }

    #[test]
    fn only_admitted_sources_complete_a_tcp_handshake_with_the_listener() {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let at = l.local_addr().unwrap();
        let mut list = AdmitList::on(at).unwrap();
        assert_eq!(list.address(), at);
        // nobody admitted: a SYN gets no answer
        assert!(dial("127.0.0.1", at).is_err());
        assert!(list.admit("127.0.0.2".parse().unwrap()));
        assert!(list.admit("127.0.0.2".parse().unwrap()));
        assert_eq!(list.admitted(), 1);
        // the admitted source gets through and its bytes arrive; another still does not
        let mut c = dial("127.0.0.2", at).expect("the admitted source connects");
        assert!(dial("127.0.0.1", at).is_err());
        let (mut s, peer) = l.accept().unwrap();
        assert_eq!(peer.ip(), "127.0.0.2".parse::<IpAddr>().unwrap());
        c.write_all(b"zenoh").unwrap();
        let mut got = [0u8; 5];
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        s.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"zenoh");
    }

    #[test]
    fn no_listener_on_the_address_is_an_error() {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let at = l.local_addr().unwrap();
        drop(l);
        assert!(AdmitList::on(at).is_err());
    }
}

//! The run's files seen from outside iceoryx2: who may use them, how much room they need, and
//! the checks that turn "iceoryx2 failed somewhere" into a sentence with what to do.
//!
//! iceoryx2 0.10 creates a run's files in two places: POSIX shared memory (`/dev/shm/<prefix>…`)
//! and its root directory (`/tmp/iceoryx2/`, static service configs, node bookkeeping, event
//! sockets). It sets modes itself with `fchmod` after creating each file (so the umask changes
//! nothing): data segments and node files end as 0600, but the per-prefix management segment
//! `…global_mgmt` is made **0666** on purpose (`enable_global_access(true)` in
//! `node/global_management_segment.rs`), static service configs 0444 and directories 0750. Any
//! other user could then overwrite the management segment and make every later node of the
//! run fail (`UnableToGenerateUniqueNodeId`, issue 10 #7).
//!
//! [`restrict_run_files`] therefore narrows every file of the run's prefix to 0600 (0700 for
//! directories) right after this process created its node and services; [`check_run_files`]
//! refuses to use a prefix that holds a file of another user (a squatter that pre-created a
//! run's segment); [`check_iceoryx_root`] refuses an iceoryx2 root directory this user cannot
//! write (a root-owned `/tmp/iceoryx2`, #18); [`check_shm_space`] compares the free space of
//! `/dev/shm` with what the fleet's services allocate ([`shm_estimate`], #16). [`preflight`]
//! runs all three before any process of a run starts.
//!
//! What is left: between iceoryx2 making `…global_mgmt` 0666 and [`restrict_run_files`]
//! narrowing it (microseconds, in the first process of the run) another user could open it
//! and keep the descriptor. Nothing short of patching iceoryx2 closes that window; the
//! README's threat model says so.

use std::ffi::CString;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::Path;

use bus_schema::names::Topic;
use bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, Grant, Intent, IntentHorizon,
    MergedHintBatch, PseudoTargetDiscovery, QHintBatch, Register, RobotState,
};

use crate::liveness::{SHM_DIR, iceoryx_root, leftover_files};
use crate::topic::limits;
use crate::{BusConfig, BusError};

/// Mode bits a regular file of a run keeps after [`restrict_run_files`]: the owner's only
/// (0600 or 0400; the owner bits themselves are iceoryx2's and are left as they are).
pub const FILE_MODE: u32 = 0o600;
/// Mode of every directory of a run after [`restrict_run_files`]: owner only.
pub const DIR_MODE: u32 = 0o700;

/// This process's effective user id.
fn euid() -> u32 {
    // SAFETY: geteuid cannot fail and has no preconditions.
    unsafe { libc::geteuid() }
}

/// Checks that no file of `prefix` belongs to another user; such a file would be opened (and
/// trusted) by iceoryx2 as part of the run.
pub fn check_run_files(prefix: &str) -> Result<(), BusError> {
    let me = euid();
    for path in leftover_files(prefix) {
        if let Ok(meta) = std::fs::symlink_metadata(&path)
            && meta.uid() != me
        {
            return Err(BusError::ForeignFile {
                path: path.display().to_string(),
                owner: meta.uid(),
                user: me,
            });
        }
    }
    Ok(())
}

/// Narrows every file of `prefix` (in `/dev/shm` and under iceoryx2's root) to its owner's bits
/// (mode & [`FILE_MODE`]),
/// its directories to [`DIR_MODE`], and the per-node directories that hold them too; returns
/// how many modes it changed.
///
/// Files of another user are an error ([`BusError::ForeignFile`]); files that vanish meanwhile
/// (a peer cleaning up) are skipped. Symlinks are never followed.
pub fn restrict_run_files(prefix: &str) -> Result<usize, BusError> {
    let me = euid();
    let nodes_dir = iceoryx_root().join("nodes");
    let mut changed = 0;
    for path in leftover_files(prefix) {
        changed += restrict_one(&path, me)?;
        // node bookkeeping lives in `<root>/nodes/<node-id>/<prefix>…`: the node's directory
        // is named by id only, so it is not in the list itself
        if let Some(dir) = path.parent()
            && dir.parent() == Some(nodes_dir.as_path())
        {
            changed += restrict_one(dir, me)?;
        }
    }
    Ok(changed)
}

fn restrict_one(path: &Path, me: u32) -> Result<usize, BusError> {
    let Ok(meta) = std::fs::symlink_metadata(path) else {
        return Ok(0); // removed meanwhile
    };
    if meta.file_type().is_symlink() {
        return Ok(0);
    }
    if meta.uid() != me {
        return Err(BusError::ForeignFile {
            path: path.display().to_string(),
            owner: meta.uid(),
            user: me,
        });
    }
    // only group/other bits go: iceoryx2 encodes a file's state in the owner bits (a static
    // service config is 0600 while in creation and 0400 when done; making it 0600 again
    // makes every later opener see "HangsInCreation")
    let want = if meta.is_dir() {
        DIR_MODE
    } else {
        meta.mode() & FILE_MODE
    };
    if meta.mode() & 0o7777 == want {
        return Ok(0);
    }
    match std::fs::set_permissions(path, std::fs::Permissions::from_mode(want)) {
        Ok(()) => Ok(1),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(0),
        Err(source) => Err(BusError::Permissions {
            path: path.display().to_string(),
            source,
        }),
    }
}

/// Checks that iceoryx2's root directory (and its subdirectories) can be used by this user:
/// absent (iceoryx2 creates it) or writable. A root-owned `/tmp/iceoryx2` left by a run as
/// root makes every node creation of an unprivileged user fail with an opaque
/// `InternalError`; this says which directory and what to do.
pub fn check_iceoryx_root() -> Result<(), BusError> {
    let root = iceoryx_root();
    let mut dirs = vec![root.clone()];
    if let Ok(entries) = std::fs::read_dir(&root) {
        dirs.extend(
            entries
                .flatten()
                .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
                .map(|e| e.path())
                // per-node directories belong to whoever ran that node; iceoryx2 only needs
                // its own
                .filter(|p| p.parent() == Some(root.as_path()) && !is_node_id_dir(p)),
        );
    }
    for dir in dirs {
        let Ok(meta) = std::fs::metadata(&dir) else {
            continue; // absent: iceoryx2 creates it
        };
        if !meta.is_dir() || !writable(&dir) {
            return Err(BusError::UnusableRoot {
                path: dir.display().to_string(),
                owner: meta.uid(),
                mode: meta.mode() & 0o7777,
                user: euid(),
            });
        }
    }
    Ok(())
}

fn is_node_id_dir(p: &Path) -> bool {
    p.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.bytes().all(|b| b.is_ascii_digit()))
}

fn writable(dir: &Path) -> bool {
    let Ok(c) = CString::new(dir.as_os_str().as_encoded_bytes()) else {
        return false;
    };
    // SAFETY: a valid NUL-terminated path.
    unsafe { libc::access(c.as_ptr(), libc::W_OK | libc::X_OK) == 0 }
}

/// Bytes of `/dev/shm` the run described by `cfg` allocates, estimated from the services'
/// limits (every segment is allocated up front when a port is created).
///
/// Per publisher, iceoryx2 sizes its data segment for every sample that can be in flight: each
/// subscriber's buffer and borrowed samples, the history and the publisher's loans. The
/// coordinator publishes once on each coordinator→robot topic, every robot once on each
/// robot→coordinator topic. Bookkeeping (connections, management segments, event services) is
/// covered by a 25 % margin plus 64 KiB per process.
pub fn shm_estimate(cfg: &BusConfig) -> u64 {
    fn segment(cfg: &BusConfig, topic: Topic, payload: usize) -> u64 {
        let l = limits(cfg, topic);
        let samples = l.max_subscribers * (l.subscriber_buffer + l.subscriber_borrowed)
            + l.history
            + l.publisher_loans;
        (samples * payload) as u64
    }
    let robots = u64::from(cfg.robots);
    let coordinator = segment(cfg, Topic::Control, size_of::<Control>())
        + segment(cfg, Topic::Merged, size_of::<MergedHintBatch>())
        + segment(cfg, Topic::Ack, size_of::<DiscoveryAck>())
        + segment(cfg, Topic::Relay, size_of::<DiscoveryRelay>())
        + segment(cfg, Topic::Grant, size_of::<Grant>());
    let robot = segment(cfg, Topic::Register, size_of::<Register>())
        + segment(cfg, Topic::RobotState, size_of::<RobotState>())
        + segment(cfg, Topic::Discovery, size_of::<PseudoTargetDiscovery>())
        + segment(cfg, Topic::Hints, size_of::<QHintBatch>())
        + segment(cfg, Topic::Report, size_of::<FinalReport>())
        + segment(cfg, Topic::Intent, size_of::<Intent>())
        + segment(cfg, Topic::Horizon, size_of::<IntentHorizon>());
    let data = coordinator + robots * robot;
    data + data / 4 + (robots + 1) * 64 * 1024
}

/// Free bytes of the filesystem at `path` for this user (`statvfs`: `f_bavail · f_frsize`).
pub fn free_bytes(path: &Path) -> Option<u64> {
    let c = CString::new(path.as_os_str().as_encoded_bytes()).ok()?;
    // SAFETY: statvfs is plain old data; zero is a valid initial value.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: a valid NUL-terminated path and a valid out-pointer.
    if unsafe { libc::statvfs(c.as_ptr(), &mut st) } != 0 {
        return None;
    }
    Some((st.f_bavail as u64).saturating_mul(st.f_frsize as u64))
}

/// Checks that `/dev/shm` has room for the run ([`shm_estimate`]); [`BusError::NoShmSpace`]
/// otherwise. A filesystem whose free space cannot be read passes (nothing to compare).
pub fn check_shm_space(cfg: &BusConfig) -> Result<(), BusError> {
    let need = shm_estimate(cfg);
    match free_bytes(Path::new(SHM_DIR)) {
        Some(have) if have < need => Err(BusError::NoShmSpace {
            need_mib: mib(need),
            have_mib: mib(have),
        }),
        _ => Ok(()),
    }
}

/// Whether `/dev/shm` is (nearly) full: less than 1 MiB free. Used to explain an iceoryx2
/// failure at run time (node id, segment or port creation) as the lack of space it is.
pub(crate) fn shm_exhausted() -> bool {
    free_bytes(Path::new(SHM_DIR)).is_some_and(|have| have < 1024 * 1024)
}

/// [`BusError::NoShmSpace`] for the run of `cfg` with what `/dev/shm` has now.
pub(crate) fn no_space(cfg: &BusConfig) -> BusError {
    BusError::NoShmSpace {
        need_mib: mib(shm_estimate(cfg)),
        have_mib: mib(free_bytes(Path::new(SHM_DIR)).unwrap_or(0)),
    }
}

fn mib(bytes: u64) -> f64 {
    (bytes as f64 / (1024.0 * 1024.0) * 10.0).ceil() / 10.0
}

/// Every check a launcher runs before it starts any process of the run described by `cfg`:
/// iceoryx2's root directory usable, no file of another user under the run's prefix, room in
/// `/dev/shm`, enough open files for the coordinator (the soft limit raised to the hard one, for
/// this process and the ones it starts).
pub fn preflight(cfg: &BusConfig) -> Result<(), BusError> {
    cfg.validate()?;
    check_iceoryx_root()?;
    check_run_files(&cfg.prefix())?;
    check_shm_space(cfg)?;
    crate::limits::check_open_files(cfg.robots)
}

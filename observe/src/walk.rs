//! Reading an MCAP recording record by record from any `Read + Seek` (a file), in bounded
//! memory, and saying exactly where a damaged one breaks.
//!
//! Why not the `mcap` crate's readers: they hold the whole file (`MessageStream` over a slice)
//! or, streaming (`sans_io::LinearReader`), load every record whole before the caller can skip
//! it (a `foxglove.Grid` of a 4096 × 4096 map is ~110 MB) and refuse to enter a chunk that a
//! killed recorder left open (its length is still the writer's placeholder `!0`). `qfleet
//! replay` read the file into a `Vec` and rebuilt a salvaged copy beside it: a damaged 1 GB file
//! took 2.1 GB, a 240 MB message 3.2 GB (issue 27).
//!
//! [`Walker`] walks the records' framing itself (opcode, length; a chunk's records inside it,
//! uncompressed, as the recorder writes them), seeks past what the caller does not want (the
//! scene channels' messages, whole chunks when only the file's shape is asked for), and loads
//! only the records asked for, each at most [`MAX_RECORD_BYTES`] (a message of a qfleet topic:
//! [`MAX_MESSAGE_BYTES`]). Memory is that one record plus the read buffer, whatever the file's
//! size. The `mcap` crate still parses the few records whose layout is not trivial (metadata,
//! attachments).
//!
//! How a walk ends ([`End`]): at the data-end record (a finished file); at the end of the file
//! in or before a record, in a file without the end magic (a recorder killed or stopped by a
//! full disk: [`End::Cut`], everything before it is read — the complete messages of a chunk
//! cut off mid-way included); anything else is [`Damage`] with the byte offset of the record
//! that broke and what was wrong with it.

use std::io::{self, Read, Seek, SeekFrom};

/// The MCAP magic that opens and closes a file.
pub const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// Largest record other than a message of a qfleet topic that a walk loads: a map attachment
/// of the largest map `planner` reads, with room for its header.
pub const MAX_RECORD_BYTES: u64 = planner::map::MAX_MAP_BYTES + (1 << 20);

/// Largest message of a qfleet topic (its JSON): the biggest wire type, a full
/// `MergedHintBatch` or `Grant`, is well under 1 MiB as JSON (a test checks it), so anything
/// near this is not a qfleet message.
pub const MAX_MESSAGE_BYTES: u64 = 4 << 20;

/// Opcodes (MCAP specification).
pub mod op {
    /// Header.
    pub const HEADER: u8 = 0x01;
    /// Footer.
    pub const FOOTER: u8 = 0x02;
    /// Schema.
    pub const SCHEMA: u8 = 0x03;
    /// Channel.
    pub const CHANNEL: u8 = 0x04;
    /// Message.
    pub const MESSAGE: u8 = 0x05;
    /// Chunk.
    pub const CHUNK: u8 = 0x06;
    /// Attachment.
    pub const ATTACHMENT: u8 = 0x09;
    /// Metadata.
    pub const METADATA: u8 = 0x0C;
    /// Data end.
    pub const DATA_END: u8 = 0x0F;
}

/// Skips up to this far are read past rather than seeked (see [`Walker::seek_to`]).
const SHORT_SKIP: u64 = 64 << 10;
/// Opcode (1 byte) and length (8 bytes) in front of every record.
const HEAD: u64 = 9;
/// A message's fields before its data: channel id u16, sequence u32, log and publish time u64.
const MESSAGE_HEAD: u64 = 2 + 4 + 8 + 8;
/// A chunk's fields before its compression string: start and end time, uncompressed size u64,
/// CRC u32, the compression string's length u32.
const CHUNK_FIXED: u64 = 8 + 8 + 8 + 4 + 4;

/// Where and why a recording cannot be read on.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("damaged at byte {at}: {what}")]
pub struct Damage {
    /// Byte offset of the record (or field) that broke.
    pub at: u64,
    /// What was wrong.
    pub what: String,
}

/// How a walk ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum End {
    /// At the data-end record: the whole data section was read.
    Finished {
        /// Offset just past the data-end record.
        at: u64,
        /// Whether the file also ends with the magic (a finished file does).
        end_magic: bool,
    },
    /// The file ends inside or right before a record and has no end magic: its recorder did
    /// not finish it. Everything before `at` was read.
    Cut {
        /// Offset of the end of the last complete record (inside a cut-off chunk: of its last
        /// complete message).
        at: u64,
    },
}

/// One record of the walk, as asked for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Item {
    /// A record loaded whole (schema, channel, metadata, attachment, header …): its opcode,
    /// offset and body.
    Record {
        /// Opcode.
        op: u8,
        /// Offset of the record.
        at: u64,
        /// Its body (after opcode and length).
        body: Vec<u8>,
    },
    /// A message the caller wanted (see [`Walker::next`]): its channel, log time, offset and data.
    Message {
        /// Channel id.
        channel: u16,
        /// Log time, ns.
        log_time: u64,
        /// Offset of the record.
        at: u64,
        /// The message's data.
        data: Vec<u8>,
    },
}

/// What to do with a message, asked of the caller by its channel id.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Want {
    /// Load it (at most [`MAX_MESSAGE_BYTES`]).
    Load,
    /// Seek past it, whatever its size.
    Skip,
    /// Its channel was never announced: the file is damaged.
    Unknown,
}

/// Walks the records of an MCAP file (see the module documentation).
pub struct Walker<R> {
    r: R,
    /// Offset of the next record.
    pos: u64,
    /// The file's length.
    len: u64,
    /// Whether the file ends with the magic.
    end_magic: bool,
    /// Inside a chunk: where its records end and where the chunk record ends.
    chunk: Option<(u64, u64)>,
    /// Whether chunks are entered (false: only the file's shape is walked, chunks are skipped
    /// unless cut off).
    enter_chunks: bool,
    /// Offset of the end of the last complete record.
    good: u64,
    ended: Option<End>,
}

/// Reads as much of `buf` as the file holds; how much.
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

fn u64_le(b: &[u8]) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[..8]);
    u64::from_le_bytes(a)
}

fn u32_le(b: &[u8]) -> u32 {
    let mut a = [0u8; 4];
    a.copy_from_slice(&b[..4]);
    u32::from_le_bytes(a)
}

/// A walk's failure: the file could not be read, or it is damaged.
#[derive(Debug, thiserror::Error)]
pub enum WalkError {
    /// Reading the file failed.
    #[error("reading the recording")]
    Io(#[from] io::Error),
    /// The file is damaged (or not MCAP).
    #[error(transparent)]
    Damaged(#[from] Damage),
}

impl<R: Read + Seek> Walker<R> {
    /// Starts a walk of `r` (`len` bytes): checks the opening magic and whether the file ends
    /// with the magic. `enter_chunks`: whether the messages inside chunks are walked (for
    /// reading them), or chunks are seeked past (for the file's shape: metadata, attachments,
    /// where it ends).
    pub fn new(mut r: R, len: u64, enter_chunks: bool) -> Result<Self, WalkError> {
        let mut magic = [0u8; 8];
        let n = read_full(&mut r, &mut magic)?;
        if n < magic.len() || &magic != MAGIC {
            return Err(Damage {
                at: 0,
                what: "it does not start with the MCAP magic: not an MCAP file".into(),
            }
            .into());
        }
        let mut end_magic = false;
        if len >= 2 * MAGIC.len() as u64 {
            r.seek(SeekFrom::Start(len - MAGIC.len() as u64))?;
            let n = read_full(&mut r, &mut magic)?;
            end_magic = n == magic.len() && &magic == MAGIC;
        }
        r.seek(SeekFrom::Start(MAGIC.len() as u64))?;
        Ok(Self {
            r,
            pos: MAGIC.len() as u64,
            len,
            end_magic,
            chunk: None,
            enter_chunks,
            good: MAGIC.len() as u64,
            ended: None,
        })
    }

    /// How the walk ended, once [`Walker::next`] returned `None`.
    pub fn end(&self) -> Option<End> {
        self.ended
    }

    /// Whether the file ends with the MCAP magic.
    pub fn has_end_magic(&self) -> bool {
        self.end_magic
    }

    /// The file's length.
    pub fn file_len(&self) -> u64 {
        self.len
    }

    /// The file ends at `at` inside (or before) the record that starts at `rec`: cut (the
    /// walk ends) in a file without the end magic, damage in one with it.
    fn cut(&mut self, rec: u64, what: impl FnOnce() -> String) -> Result<Option<Item>, WalkError> {
        if self.end_magic {
            return Err(Damage {
                at: rec,
                what: what(),
            }
            .into());
        }
        self.ended = Some(End::Cut { at: self.good });
        Ok(None)
    }

    /// Moves to `at`: a short step forward is read past (a buffered reader keeps its buffer,
    /// one small skipped message costs no system call), a long one or a step back is a seek.
    fn seek_to(&mut self, at: u64) -> io::Result<()> {
        match at.checked_sub(self.pos) {
            Some(n) if n <= SHORT_SKIP => {
                let skipped = io::copy(&mut (&mut self.r).take(n), &mut io::sink())?;
                self.pos += skipped;
                if skipped < n {
                    // the file ended: the next read finds it so
                    self.r.seek(SeekFrom::Start(at))?;
                    self.pos = at;
                }
            }
            _ => {
                self.r.seek(SeekFrom::Start(at))?;
                self.pos = at;
            }
        }
        Ok(())
    }

    /// Reads `n` bytes at the current position (n ≤ what the caller bounded); fewer if the
    /// file ends.
    fn read_n(&mut self, n: u64) -> io::Result<Vec<u8>> {
        let mut buf = Vec::new();
        (&mut self.r).take(n).read_to_end(&mut buf)?;
        self.pos += buf.len() as u64;
        Ok(buf)
    }

    /// The next record the caller wants: `want(channel)` decides about each message. `None`
    /// when the walk ended (see [`Walker::end`]).
    pub fn next(&mut self, mut want: impl FnMut(u16) -> Want) -> Result<Option<Item>, WalkError> {
        loop {
            if self.ended.is_some() {
                return Ok(None);
            }
            let at = self.pos;
            // inside a chunk: its records end at `records_end`
            let limit = match self.chunk {
                Some((records_end, chunk_end)) if at >= records_end => {
                    // the chunk's padding, if any, then the next top-level record
                    self.chunk = None;
                    self.good = chunk_end;
                    self.seek_to(chunk_end)?;
                    continue;
                }
                Some((records_end, _)) => records_end,
                None => self.len,
            };
            if at == self.len {
                let what = || "the file ends where a record should start".to_string();
                return self.cut(at, what);
            }
            let head = self.read_n(HEAD)?;
            if head.len() < HEAD as usize {
                return self.cut(at, || "the file ends inside a record's head".into());
            }
            let opcode = head[0];
            let body_len = u64_le(&head[1..]);
            let end = at.checked_add(HEAD).and_then(|x| x.checked_add(body_len));
            let in_chunk = self.chunk.is_some();
            if opcode == 0 || (0x10..0x80).contains(&opcode) {
                return Err(Damage {
                    at,
                    what: format!("unknown record opcode {opcode:#04x}"),
                }
                .into());
            }
            if in_chunk && matches!(opcode, op::CHUNK | op::DATA_END | op::FOOTER | op::HEADER) {
                return Err(Damage {
                    at,
                    what: format!("a record of opcode {opcode:#04x} inside a chunk"),
                }
                .into());
            }
            if opcode == op::CHUNK {
                match self.chunk_at(at, body_len, end)? {
                    Some(()) => continue,
                    None => return Ok(None),
                }
            }
            if opcode == op::DATA_END || opcode == op::FOOTER {
                // the data section ended whole: what follows is the summary
                let end = end.filter(|&e| e <= self.len).unwrap_or(self.len);
                self.good = end;
                self.ended = Some(End::Finished {
                    at: end,
                    end_magic: self.end_magic,
                });
                return Ok(None);
            }
            let Some(end) = end.filter(|&e| e <= limit) else {
                if limit < self.len || end.is_some_and(|e| e <= self.len) {
                    // within the file, past its chunk: the framing is broken
                    return Err(Damage {
                        at,
                        what: format!(
                            "a record of opcode {opcode:#04x} and {body_len} bytes runs past the \
                             end of its chunk"
                        ),
                    }
                    .into());
                }
                return self.cut(at, || {
                    format!(
                        "a record of opcode {opcode:#04x} claims {body_len} bytes, past the end \
                         of the file"
                    )
                });
            };
            if opcode == op::MESSAGE {
                if body_len < MESSAGE_HEAD {
                    return Err(Damage {
                        at,
                        what: format!(
                            "a message record of {body_len} bytes, shorter than its header"
                        ),
                    }
                    .into());
                }
                let mh = self.read_n(MESSAGE_HEAD)?;
                let channel = u16::from_le_bytes([mh[0], mh[1]]);
                let log_time = u64_le(&mh[6..]);
                let data_len = body_len - MESSAGE_HEAD;
                match want(channel) {
                    Want::Skip => {
                        self.seek_to(end)?;
                        self.good = end;
                        continue;
                    }
                    Want::Unknown => {
                        return Err(Damage {
                            at,
                            what: format!(
                                "a message on channel {channel}, which no channel record announced"
                            ),
                        }
                        .into());
                    }
                    Want::Load if data_len > MAX_MESSAGE_BYTES => {
                        return Err(Damage {
                            at,
                            what: format!(
                                "a message of {data_len} bytes on channel {channel}; a qfleet \
                                 message is at most {MAX_MESSAGE_BYTES} bytes"
                            ),
                        }
                        .into());
                    }
                    Want::Load => {
                        let data = self.read_n(data_len)?;
                        if (data.len() as u64) < data_len {
                            return self.cut(at, || "the file ends inside a message".into());
                        }
                        self.good = end;
                        return Ok(Some(Item::Message {
                            channel,
                            log_time,
                            at,
                            data,
                        }));
                    }
                }
            }
            if body_len > MAX_RECORD_BYTES {
                return Err(Damage {
                    at,
                    what: format!(
                        "a record of opcode {opcode:#04x} and {body_len} bytes, more than the \
                         {MAX_RECORD_BYTES} a qfleet recording's records hold"
                    ),
                }
                .into());
            }
            let body = self.read_n(body_len)?;
            if (body.len() as u64) < body_len {
                return self.cut(at, || "the file ends inside a record".into());
            }
            self.good = end;
            return Ok(Some(Item::Record {
                op: opcode,
                at,
                body,
            }));
        }
    }

    /// At a chunk record at `at`: seeks past it when it is whole and chunks are not entered;
    /// otherwise enters it (reads its header). `Some(())` to go on, `None` when the walk ended.
    fn chunk_at(
        &mut self,
        at: u64,
        body_len: u64,
        end: Option<u64>,
    ) -> Result<Option<()>, WalkError> {
        let whole = end.is_some_and(|e| e <= self.len);
        if whole && !self.enter_chunks {
            let end = end.unwrap_or(self.len);
            self.good = end;
            self.seek_to(end)?;
            return Ok(Some(()));
        }
        let fixed = self.read_n(CHUNK_FIXED)?;
        if (fixed.len() as u64) < CHUNK_FIXED {
            return self
                .cut(at, || "the file ends inside a chunk's header".into())
                .map(|_| None);
        }
        let compression_len = u64::from(u32_le(&fixed[28..]));
        if compression_len > 0 {
            // qfleet writes uncompressed chunks; this reader reads no other (and the `mcap`
            // crate is built without zstd/lz4)
            return Err(Damage {
                at,
                what: format!(
                    "a compressed chunk (compression name of {compression_len} bytes): qfleet \
                     recordings are uncompressed"
                ),
            }
            .into());
        }
        let rl = self.read_n(8)?;
        if rl.len() < 8 {
            return self
                .cut(at, || "the file ends inside a chunk's header".into())
                .map(|_| None);
        }
        let records_len = u64_le(&rl);
        let records_at = at + HEAD + CHUNK_FIXED + 8;
        let records_end = records_at.saturating_add(records_len);
        if whole {
            let end = end.unwrap_or(self.len);
            if body_len < CHUNK_FIXED + 8 || records_end > end {
                return Err(Damage {
                    at,
                    what: format!(
                        "a chunk of {body_len} bytes whose records claim {records_len} bytes"
                    ),
                }
                .into());
            }
            self.chunk = Some((records_end, end));
        } else {
            // cut off (a recorder killed mid-chunk leaves its placeholder lengths): its
            // complete records are read, up to the end of the file
            if self.end_magic {
                return Err(Damage {
                    at,
                    what: format!("a chunk claims {body_len} bytes, past the end of the file"),
                }
                .into());
            }
            self.chunk = Some((records_end.min(self.len), self.len));
        }
        Ok(Some(()))
    }
}

/// The file's shape, from a walk that seeks past whole chunks: the records outside chunks
/// (metadata, attachments, schemas, channels) and how it ends.
pub fn outline<R: Read + Seek>(
    r: R,
    len: u64,
    mut on_record: impl FnMut(u8, u64, &[u8]) -> Result<(), Damage>,
) -> Result<End, WalkError> {
    let mut w = Walker::new(r, len, false)?;
    // a message outside chunks is skipped here (it is read with the rest)
    while let Some(item) = w.next(|_| Want::Skip)? {
        if let Item::Record { op, at, body } = item {
            on_record(op, at, &body)?;
        }
    }
    // a chunk cut off mid-way was walked into (its complete messages count as read)
    Ok(w.end().unwrap_or(End::Cut {
        at: MAGIC.len() as u64,
    }))
}

/// A channel record's id and topic (the rest of it is not needed).
pub fn channel_of(at: u64, body: &[u8]) -> Result<(u16, String), Damage> {
    let bad = || Damage {
        at,
        what: "a channel record that does not parse".into(),
    };
    if body.len() < 8 {
        return Err(bad());
    }
    let id = u16::from_le_bytes([body[0], body[1]]);
    let n = u32_le(&body[4..]) as usize;
    let topic = body
        .get(8..8usize.checked_add(n).ok_or_else(bad)?)
        .ok_or_else(bad)?;
    let topic = std::str::from_utf8(topic).map_err(|_| bad())?;
    Ok((id, topic.to_string()))
}

/// Reads the fields of one record's body, each checked against its end.
struct Fields<'a> {
    b: &'a [u8],
    i: usize,
    at: u64,
    what: &'static str,
}

impl<'a> Fields<'a> {
    fn bad(&self) -> Damage {
        Damage {
            at: self.at,
            what: format!("a {} record that does not parse", self.what),
        }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], Damage> {
        let end = self.i.checked_add(n).ok_or_else(|| self.bad())?;
        let s = self.b.get(self.i..end).ok_or_else(|| self.bad())?;
        self.i = end;
        Ok(s)
    }
    fn u32(&mut self) -> Result<u32, Damage> {
        Ok(u32_le(self.take(4)?))
    }
    fn u64(&mut self) -> Result<u64, Damage> {
        Ok(u64_le(self.take(8)?))
    }
    fn str(&mut self) -> Result<String, Damage> {
        let n = self.u32()? as usize;
        let s = self.take(n)?;
        std::str::from_utf8(s)
            .map(str::to_string)
            .map_err(|_| self.bad())
    }
}

/// A metadata record's name and key–value pairs.
pub fn metadata_of(
    at: u64,
    body: &[u8],
) -> Result<(String, std::collections::BTreeMap<String, String>), Damage> {
    let mut f = Fields {
        b: body,
        i: 0,
        at,
        what: "metadata",
    };
    let name = f.str()?;
    let n = f.u32()? as usize;
    let mut m = Fields {
        b: f.take(n)?,
        i: 0,
        at,
        what: "metadata",
    };
    let mut map = std::collections::BTreeMap::new();
    while m.i < m.b.len() {
        let k = m.str()?;
        let v = m.str()?;
        map.insert(k, v);
    }
    Ok((name, map))
}

/// An attachment record's name and data.
pub fn attachment_of(at: u64, body: &[u8]) -> Result<(String, &[u8]), Damage> {
    let mut f = Fields {
        b: body,
        i: 0,
        at,
        what: "attachment",
    };
    f.u64()?; // log time
    f.u64()?; // create time
    let name = f.str()?;
    f.str()?; // media type
    let n = usize::try_from(f.u64()?).map_err(|_| f.bad())?;
    let data = f.take(n)?;
    Ok((name, data))
}

//! Reading what a recorder that did not finish left behind: a `qfleet run --record` killed
//! (SIGKILL, the OOM killer, a power cut) or stopped by a full disk leaves an MCAP file with
//! no summary, no end magic and, usually, a chunk cut off in the middle, whose length field
//! still holds the writer's placeholder. The `mcap` crate's readers refuse such a file (seen:
//! "record with opcode 06 length exceeds limit").
//!
//! [`salvage`] rebuilds a valid MCAP file from it without IO: every complete record up to the
//! damage is kept byte for byte (so offsets stay right), the complete records inside a cut-off
//! uncompressed chunk (the recorder writes no compression) are lifted out of it, and a data-end
//! record, an empty footer and the end magic close the file. What came after the last complete
//! record is lost; [`Salvaged::kept_bytes`] says how much of the file was used.

/// The MCAP magic that opens and closes a file.
pub const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

const OP_FOOTER: u8 = 0x02;
const OP_CHUNK: u8 = 0x06;
const OP_DATA_END: u8 = 0x0F;
/// Opcode (1 byte) and length (8 bytes) in front of every record.
const RECORD_HEAD: usize = 9;

/// A damaged recording made readable.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Salvaged {
    /// The rebuilt file: a valid MCAP file holding every complete record.
    pub bytes: Vec<u8>,
    /// How many bytes of the damaged file the complete records came from (from its start).
    pub kept_bytes: u64,
}

/// Whether `bytes` looks like a finished MCAP file (magic at both ends); one that does not is
/// worth a [`salvage`].
pub fn is_finished(bytes: &[u8]) -> bool {
    bytes.len() >= 2 * MAGIC.len() && bytes.starts_with(MAGIC) && bytes.ends_with(MAGIC)
}

fn u64_at(bytes: &[u8], at: usize) -> Option<u64> {
    let b = bytes.get(at..at.checked_add(8)?)?;
    Some(u64::from_le_bytes(b.try_into().ok()?))
}

fn u32_at(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes(b.try_into().ok()?))
}

/// The end of the complete record starting at `at` in `bytes`, if it is complete.
fn record_end(bytes: &[u8], at: usize) -> Option<usize> {
    let len = usize::try_from(u64_at(bytes, at + 1)?).ok()?;
    let end = at.checked_add(RECORD_HEAD)?.checked_add(len)?;
    (end <= bytes.len()).then_some(end)
}

/// The complete records inside the body of a chunk that was cut off (`body` runs from the
/// chunk's first field to the end of the file), if the chunk is uncompressed, and how many
/// bytes of `body` they end at (0 when there are none).
fn records_of_cut_chunk(body: &[u8]) -> (Vec<&[u8]>, usize) {
    // message_start_time u64, message_end_time u64, uncompressed_size u64,
    // uncompressed_crc u32, compression (u32 length + bytes), records (u64 length + bytes)
    const RECORDS_AT: usize = 8 + 8 + 8 + 4 + 4 + 8;
    if u32_at(body, 28) != Some(0) || body.len() < RECORDS_AT {
        return (Vec::new(), 0);
    }
    let records = &body[RECORDS_AT..];
    let mut found = Vec::new();
    let mut at = 0;
    while let Some(end) = record_end(records, at) {
        found.push(&records[at..end]);
        at = end;
    }
    let used = if found.is_empty() { 0 } else { RECORDS_AT + at };
    (found, used)
}

/// Rebuilds a readable MCAP file from a recording that was not finished; `None` if `bytes`
/// does not even start like an MCAP file.
pub fn salvage(bytes: &[u8]) -> Option<Salvaged> {
    if !bytes.starts_with(MAGIC) {
        return None;
    }
    let mut out = Vec::with_capacity(bytes.len() + 64);
    out.extend_from_slice(MAGIC);
    let mut at = MAGIC.len();
    while at + RECORD_HEAD <= bytes.len() {
        let op = bytes[at];
        if op == OP_DATA_END || op == OP_FOOTER {
            // the data section ended whole: what follows is the summary
            break;
        }
        match record_end(bytes, at) {
            Some(end) => {
                out.extend_from_slice(&bytes[at..end]);
                at = end;
            }
            None => {
                if op == OP_CHUNK {
                    let (records, used) = records_of_cut_chunk(&bytes[at + RECORD_HEAD..]);
                    for r in &records {
                        out.extend_from_slice(r);
                    }
                    if used > 0 {
                        at += RECORD_HEAD + used;
                    }
                }
                break;
            }
        }
    }
    let kept_bytes = at as u64;
    // data end (data section CRC 0: not computed), an empty footer, the end magic
    out.push(OP_DATA_END);
    out.extend_from_slice(&4u64.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.push(OP_FOOTER);
    out.extend_from_slice(&20u64.to_le_bytes());
    out.extend_from_slice(&[0u8; 20]);
    out.extend_from_slice(MAGIC);
    Some(Salvaged {
        bytes: out,
        kept_bytes,
    })
}

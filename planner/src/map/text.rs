//! Line splitting shared by the parsers: UTF-8 checked line by line, a trailing `\r` and a
//! leading byte-order mark dropped, so Windows-edited files read like Unix ones.

use super::{Location, MapError};

/// One line of a map or scenario file.
pub(crate) struct Line<'a> {
    /// 1-based line number.
    pub number: usize,
    /// The line without its `\n` or `\r\n`.
    pub text: &'a str,
}

impl Line<'_> {
    /// Whether the line holds nothing but whitespace.
    pub fn is_blank(&self) -> bool {
        self.text.trim().is_empty()
    }

    /// The 1-based character column of byte offset `byte` in this line.
    pub fn column_of(&self, byte: usize) -> usize {
        self.text
            .get(..byte)
            .map_or(1, |prefix| prefix.chars().count() + 1)
    }
}

/// The lines of `bytes`, or a [`MapError::NotUtf8`] naming the first bad byte's line and column.
///
/// A file ending in a newline yields one last empty line; the parsers treat trailing blank lines
/// as nothing.
pub(crate) fn lines<'a>(
    source: &'a str,
    bytes: &'a [u8],
) -> impl Iterator<Item = Result<Line<'a>, MapError>> + 'a {
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    bytes
        .split(|b| *b == b'\n')
        .enumerate()
        .map(move |(i, raw)| {
            let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
            match std::str::from_utf8(raw) {
                Ok(text) => Ok(Line {
                    number: i + 1,
                    text,
                }),
                Err(e) => {
                    let good = std::str::from_utf8(&raw[..e.valid_up_to()])
                        .map_or(0, |s| s.chars().count());
                    Err(MapError::NotUtf8 {
                        at: Location::at(source, i + 1, good + 1),
                    })
                }
            }
        })
}

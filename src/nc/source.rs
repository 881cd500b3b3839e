//! Seekable line sources: a program in memory or a file read through a buffer, so a long
//! program is never held in memory and O-word loops and subroutines can jump back.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;
use std::sync::Arc;

/// A reading position: file index, byte offset, 1-based number of the next line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Pos {
    /// Index into the interpreter's list of sources.
    pub file: usize,
    /// Byte offset of the next line.
    pub offset: u64,
    /// 1-based number of the next line.
    pub line: usize,
}

/// Bytes read from a file at a time.
const FILE_BUFFER: usize = 1 << 16;

enum Data {
    /// The whole text; the reading position is [`Source::offset`].
    Mem(Arc<[u8]>),
    /// A file read through `buf`, whose unread part is `buf[start..end]`.
    File {
        file: File,
        buf: Box<[u8]>,
        start: usize,
        end: usize,
    },
}

/// One source file.
pub(crate) struct Source {
    /// Path (for messages and output records).
    pub path: Arc<Path>,
    data: Data,
    offset: u64,
    line: usize,
}

impl Source {
    /// A source over text in memory.
    pub fn from_bytes(bytes: Arc<[u8]>, path: &Path) -> Source {
        Source {
            path: Arc::from(path),
            data: Data::Mem(bytes),
            offset: 0,
            line: 1,
        }
    }

    /// A source reading `path` through a buffer.
    pub fn open(path: &Path) -> std::io::Result<Source> {
        let f = File::open(path)?;
        Ok(Source {
            path: Arc::from(path),
            data: Data::File {
                file: f,
                buf: vec![0; FILE_BUFFER].into_boxed_slice(),
                start: 0,
                end: 0,
            },
            offset: 0,
            line: 1,
        })
    }

    /// Reads the next line into `buf` (without the line end). Returns false at the end.
    pub fn read_line(&mut self, buf: &mut Vec<u8>) -> std::io::Result<bool> {
        buf.clear();
        let n = match &mut self.data {
            Data::Mem(bytes) => {
                let from = usize::try_from(self.offset).unwrap_or(usize::MAX);
                let rest = bytes.get(from..).unwrap_or(&[]);
                let len = find_newline(rest).map_or(rest.len(), |p| p + 1);
                buf.extend_from_slice(&rest[..len]);
                len
            }
            Data::File {
                file,
                buf: fbuf,
                start,
                end,
            } => {
                let mut total = 0;
                loop {
                    if *start == *end {
                        *end = read_some(file, fbuf)?;
                        *start = 0;
                        if *end == 0 {
                            break;
                        }
                    }
                    let avail = &fbuf[*start..*end];
                    if let Some(p) = find_newline(avail) {
                        buf.extend_from_slice(&avail[..=p]);
                        *start += p + 1;
                        total += p + 1;
                        break;
                    }
                    buf.extend_from_slice(avail);
                    total += avail.len();
                    *start = *end;
                }
                total
            }
        };
        if n == 0 {
            return Ok(false);
        }
        self.offset += n as u64;
        self.line += 1;
        if buf.last() == Some(&b'\n') {
            buf.pop();
        }
        if buf.last() == Some(&b'\r') {
            buf.pop();
        }
        Ok(true)
    }

    /// Offset and number of the next line.
    pub fn tell(&self) -> (u64, usize) {
        (self.offset, self.line)
    }

    /// Moves to a position returned by [`Source::tell`].
    pub fn seek(&mut self, offset: u64, line: usize) -> std::io::Result<()> {
        if let Data::File {
            file, start, end, ..
        } = &mut self.data
        {
            file.seek(SeekFrom::Start(offset))?;
            *start = 0;
            *end = 0;
        }
        self.offset = offset;
        self.line = line;
        Ok(())
    }
}

/// One `read` into `buf`, retried when interrupted; 0 at the end of the file.
fn read_some(file: &mut File, buf: &mut [u8]) -> std::io::Result<usize> {
    loop {
        match file.read(buf) {
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            r => return r,
        }
    }
}

/// Position of the first `\n` in `s`, eight bytes at a time (program lines are short, so
/// this beats a general search's setup).
fn find_newline(s: &[u8]) -> Option<usize> {
    const ONES: u64 = 0x0101_0101_0101_0101;
    const HIGHS: u64 = 0x8080_8080_8080_8080;
    const NEWLINES: u64 = 0x0a0a_0a0a_0a0a_0a0a;
    let chunks = s.chunks_exact(8);
    let tail = chunks.remainder();
    for (c, chunk) in chunks.enumerate() {
        let mut word = [0u8; 8];
        word.copy_from_slice(chunk);
        let x = u64::from_le_bytes(word) ^ NEWLINES;
        // the lowest byte that was '\n' is the lowest with its high bit set here
        let hit = x.wrapping_sub(ONES) & !x & HIGHS;
        if hit != 0 {
            return Some(c * 8 + (hit.trailing_zeros() / 8) as usize);
        }
    }
    let base = s.len() - tail.len();
    tail.iter().position(|&b| b == b'\n').map(|p| base + p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn find_newline_agrees_with_a_plain_search() {
        let text = b"G1 X1\nabcdefgh\n\n\x8a\x0b\x09\xff\n0123456789abcdef";
        for from in 0..text.len() {
            for to in from..=text.len() {
                let s = &text[from..to];
                assert_eq!(
                    find_newline(s),
                    s.iter().position(|&b| b == b'\n'),
                    "{from}..{to}"
                );
            }
        }
    }

    #[test]
    fn lines_across_buffer_refills_and_seeks() {
        let dir = std::env::temp_dir().join(format!("twinmill-source-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let path = dir.join("long.ngc");
        let mut text = String::new();
        for k in 0..20_000 {
            text.push_str(&format!("G1 X{k} Y{}\r\n", k % 7));
        }
        text.push_str("M2");
        std::fs::write(&path, &text).expect("written");
        let mut file = Source::open(&path).expect("opens");
        let mut mem = Source::from_bytes(Arc::from(text.as_bytes()), &path);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let mut lines = 0;
        let mut mark = None;
        loop {
            let more = file.read_line(&mut a).expect("reads");
            assert_eq!(more, mem.read_line(&mut b).expect("reads"));
            if !more {
                break;
            }
            let expected = text
                .lines()
                .nth(lines)
                .expect("line")
                .trim_end_matches('\r');
            assert_eq!(a, expected.as_bytes());
            assert_eq!(a, b);
            assert_eq!(file.tell(), mem.tell());
            lines += 1;
            if lines == 9_000 {
                mark = Some(file.tell());
            }
        }
        assert_eq!(lines, 20_001);
        let (offset, line) = mark.expect("marked");
        file.seek(offset, line).expect("seeks");
        mem.seek(offset, line).expect("seeks");
        assert!(file.read_line(&mut a).expect("reads"));
        assert!(mem.read_line(&mut b).expect("reads"));
        assert_eq!(a, b"G1 X9000 Y5");
        assert_eq!(a, b);
        let _ = std::fs::remove_dir_all(&dir);
    }
}

//! Seekable line sources: a program in memory or a file read through a buffer, so a long
//! program is never held in memory and O-word loops and subroutines can jump back.

use std::fs::File;
use std::io::{BufRead, BufReader, Cursor, Seek, SeekFrom};
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

enum Data {
    Mem(Cursor<Arc<[u8]>>),
    File(BufReader<File>),
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
            data: Data::Mem(Cursor::new(bytes)),
            offset: 0,
            line: 1,
        }
    }

    /// A source reading `path` through a buffer.
    pub fn open(path: &Path) -> std::io::Result<Source> {
        let f = File::open(path)?;
        Ok(Source {
            path: Arc::from(path),
            data: Data::File(BufReader::with_capacity(1 << 16, f)),
            offset: 0,
            line: 1,
        })
    }

    /// Reads the next line into `buf` (without the line end). Returns false at the end.
    pub fn read_line(&mut self, buf: &mut Vec<u8>) -> std::io::Result<bool> {
        buf.clear();
        let n = match &mut self.data {
            Data::Mem(c) => c.read_until(b'\n', buf)?,
            Data::File(f) => f.read_until(b'\n', buf)?,
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
        match &mut self.data {
            Data::Mem(c) => {
                c.seek(SeekFrom::Start(offset))?;
            }
            Data::File(f) => {
                f.seek(SeekFrom::Start(offset))?;
            }
        }
        self.offset = offset;
        self.line = line;
        Ok(())
    }
}

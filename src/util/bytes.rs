//! Little-endian byte codecs: the writers ([`Sink`] and the `put_*` functions) and the [`Reader`] behind
//! the block format ([`crate::serialise`]) and the checkpoint file ([`crate::checkpoint`]). Every float
//! travels as its exact bits.

use std::fmt;

/// Where encoded bytes go: a byte vector, or a [`Counter`] that only counts them.
pub trait Sink {
    /// Appends bytes.
    fn put(&mut self, b: &[u8]);
    /// Announces `n` bytes of bulk data; returns true when the sink only counts (the caller may then skip
    /// producing them).
    fn bulk(&mut self, n: usize) -> bool;
}

impl Sink for Vec<u8> {
    fn put(&mut self, b: &[u8]) {
        self.extend_from_slice(b);
    }
    fn bulk(&mut self, n: usize) -> bool {
        self.reserve(n);
        false
    }
}

/// A sink that counts the bytes it is given (the length of an encoding without writing it).
#[derive(Clone, Copy, Debug, Default)]
pub struct Counter(pub usize);

impl Sink for Counter {
    fn put(&mut self, b: &[u8]) {
        self.0 += b.len();
    }
    fn bulk(&mut self, n: usize) -> bool {
        self.0 += n;
        true
    }
}

/// Writes one byte.
pub fn put_u8(s: &mut impl Sink, v: u8) {
    s.put(&[v]);
}
/// Writes a u32, little-endian.
pub fn put_u32(s: &mut impl Sink, v: u32) {
    s.put(&v.to_le_bytes());
}
/// Writes a u64, little-endian.
pub fn put_u64(s: &mut impl Sink, v: u64) {
    s.put(&v.to_le_bytes());
}
/// Writes the exact bits of an f64, little-endian.
pub fn put_f64(s: &mut impl Sink, v: f64) {
    s.put(&v.to_bits().to_le_bytes());
}
/// Writes a short string: a u8 length, then at most 255 bytes of it.
pub fn put_str8(s: &mut impl Sink, text: &str) {
    let b = &text.as_bytes()[..text.len().min(255)];
    put_u8(s, b.len() as u8);
    s.put(b);
}
/// Writes a u64 count, then the values.
pub fn put_f64s(s: &mut impl Sink, xs: &[f64]) {
    put_u64(s, xs.len() as u64);
    for &x in xs {
        put_f64(s, x);
    }
}

/// Why bytes could not be read: the section and what was wrong (one line).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ReadError(pub String);

impl fmt::Display for ReadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ReadError {}

/// A cursor over little-endian bytes of one named section; every read checks the bytes left.
pub struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
    section: &'static str,
}

impl<'a> Reader<'a> {
    /// A reader of `b`, the bytes of section `section` (named in errors).
    pub fn new(b: &'a [u8], section: &'static str) -> Self {
        Reader { b, pos: 0, section }
    }
    /// Bytes read so far.
    pub fn pos(&self) -> usize {
        self.pos
    }
    /// Whether every byte has been read (an optional field at the end is absent).
    pub fn at_end(&self) -> bool {
        self.pos == self.b.len()
    }
    /// An error of this section: `section <name>: <what>`.
    pub fn bad(&self, what: impl fmt::Display) -> ReadError {
        ReadError(format!("section {}: {what}", self.section))
    }
    /// The next `n` bytes.
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], ReadError> {
        if self.b.len() - self.pos < n {
            return Err(self.bad(format_args!("ends after {} of {} bytes", self.b.len(), self.pos + n)));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    /// One byte.
    pub fn u8(&mut self) -> Result<u8, ReadError> {
        Ok(self.take(1)?[0])
    }
    /// A little-endian u32.
    pub fn u32(&mut self) -> Result<u32, ReadError> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }
    /// A little-endian u64.
    pub fn u64(&mut self) -> Result<u64, ReadError> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
    /// An f64 from its exact bits.
    pub fn f64(&mut self) -> Result<f64, ReadError> {
        Ok(f64::from_bits(self.u64()?))
    }
    /// A flag byte, 0 or 1.
    pub fn bool(&mut self) -> Result<bool, ReadError> {
        match self.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            v => Err(self.bad(format_args!("flag byte {v}"))),
        }
    }
    /// A short string written by [`put_str8`].
    pub fn str8(&mut self) -> Result<String, ReadError> {
        let n = self.u8()? as usize;
        let b = self.take(n)?;
        String::from_utf8(b.to_vec()).map_err(|_| self.bad("not text"))
    }
    /// A u32 entry count, checked against the bytes left (each entry takes at least `entry` bytes).
    pub fn count(&mut self, entry: usize) -> Result<usize, ReadError> {
        let n = self.u32()? as usize;
        self.fits(n, entry)
    }
    /// A u64 entry count, checked like [`Reader::count`].
    pub fn count64(&mut self, entry: usize) -> Result<usize, ReadError> {
        let n = usize::try_from(self.u64()?).unwrap_or(usize::MAX);
        self.fits(n, entry)
    }
    fn fits(&self, n: usize, entry: usize) -> Result<usize, ReadError> {
        if n.saturating_mul(entry) > self.b.len() - self.pos {
            return Err(self.bad(format_args!("{n} entries of {entry} bytes do not fit")));
        }
        Ok(n)
    }
    /// A u64 count and that many f64 values ([`put_f64s`]).
    pub fn f64s(&mut self) -> Result<Vec<f64>, ReadError> {
        let n = self.count64(8)?;
        (0..n).map(|_| self.f64()).collect()
    }
    /// Checks that every byte was read.
    pub fn finish(&self) -> Result<(), ReadError> {
        if self.pos != self.b.len() {
            return Err(self.bad(format_args!("{} bytes left over", self.b.len() - self.pos)));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_round_trip_and_short_input_is_an_error() {
        let mut v = Vec::new();
        put_u8(&mut v, 7);
        put_u32(&mut v, 0xdead_beef);
        put_u64(&mut v, u64::MAX - 1);
        put_f64(&mut v, -0.0);
        put_str8(&mut v, "héllo");
        put_f64s(&mut v, &[1.5, f64::NAN]);
        let mut c = Counter(0);
        put_u64(&mut c, 1);
        assert_eq!(c.0, 8);
        let mut r = Reader::new(&v, "test");
        assert_eq!(r.u8().unwrap(), 7);
        assert_eq!(r.u32().unwrap(), 0xdead_beef);
        assert_eq!(r.u64().unwrap(), u64::MAX - 1);
        assert_eq!(r.f64().unwrap().to_bits(), (-0.0f64).to_bits());
        assert_eq!(r.str8().unwrap(), "héllo");
        let xs = r.f64s().unwrap();
        assert_eq!((xs[0], xs[1].is_nan()), (1.5, true));
        r.finish().unwrap();
        assert!(r.u8().unwrap_err().to_string().starts_with("section test: ends after"));
        let mut r = Reader::new(&[5, 0, 0, 0], "counts");
        assert!(r.count(8).is_err());
    }
}

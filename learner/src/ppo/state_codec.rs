//! The byte layout of a learner's training state: little-endian numbers, lengths before
//! lists, written and read in the same order (`saved_state` holds the order). Reading checks
//! every length against what is left, so a damaged state is an error, never a panic or a
//! huge allocation.

/// Why a saved training state does not read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("training state: {0}")]
pub struct StateError(pub String);

/// Appends values to a byte buffer.
#[derive(Debug, Default)]
pub(super) struct StateWriter {
    bytes: Vec<u8>,
}

impl StateWriter {
    pub(super) fn u32(&mut self, v: u32) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }

    pub(super) fn u64(&mut self, v: u64) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }

    pub(super) fn u128(&mut self, v: u128) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }

    pub(super) fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }

    pub(super) fn bytes(&mut self, v: &[u8]) {
        self.u64(v.len() as u64);
        self.bytes.extend_from_slice(v);
    }

    pub(super) fn f32s(&mut self, v: &[f32]) {
        self.u64(v.len() as u64);
        self.bytes.reserve(v.len() * 4);
        for x in v {
            self.bytes.extend_from_slice(&x.to_le_bytes());
        }
    }

    pub(super) fn finish(self) -> Vec<u8> {
        self.bytes
    }
}

/// Reads values back in the order they were written.
#[derive(Debug)]
pub(super) struct StateReader<'a> {
    bytes: &'a [u8],
}

impl<'a> StateReader<'a> {
    pub(super) fn new(bytes: &'a [u8]) -> Self {
        Self { bytes }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], StateError> {
        if self.bytes.len() < n {
            return Err(StateError(format!(
                "{what}: {n} bytes wanted, {} left",
                self.bytes.len()
            )));
        }
        let (head, rest) = self.bytes.split_at(n);
        self.bytes = rest;
        Ok(head)
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], StateError> {
        let mut a = [0; N];
        a.copy_from_slice(self.take(N, what)?);
        Ok(a)
    }

    pub(super) fn u32(&mut self, what: &str) -> Result<u32, StateError> {
        self.array(what).map(u32::from_le_bytes)
    }

    pub(super) fn u64(&mut self, what: &str) -> Result<u64, StateError> {
        self.array(what).map(u64::from_le_bytes)
    }

    pub(super) fn u128(&mut self, what: &str) -> Result<u128, StateError> {
        self.array(what).map(u128::from_le_bytes)
    }

    pub(super) fn f64(&mut self, what: &str) -> Result<f64, StateError> {
        self.u64(what).map(f64::from_bits)
    }

    /// A count of items of at least `item_bytes` bytes each, checked against what is left.
    pub(super) fn count(&mut self, item_bytes: usize, what: &str) -> Result<usize, StateError> {
        let n = self.u64(what)?;
        let fits = usize::try_from(n)
            .ok()
            .filter(|&n| n.saturating_mul(item_bytes.max(1)) <= self.bytes.len());
        fits.ok_or_else(|| {
            StateError(format!(
                "{what}: {n} items do not fit in the {} bytes left",
                self.bytes.len()
            ))
        })
    }

    pub(super) fn bytes(&mut self, what: &str) -> Result<Vec<u8>, StateError> {
        let n = self.count(1, what)?;
        Ok(self.take(n, what)?.to_vec())
    }

    pub(super) fn f32s(&mut self, what: &str) -> Result<Vec<f32>, StateError> {
        let n = self.count(4, what)?;
        let raw = self.take(n * 4, what)?;
        Ok(raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }

    /// Checks that nothing is left over.
    pub(super) fn end(&self) -> Result<(), StateError> {
        if self.bytes.is_empty() {
            Ok(())
        } else {
            Err(StateError(format!(
                "{} bytes left over at the end",
                self.bytes.len()
            )))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_come_back_in_order_and_a_cut_state_is_an_error() {
        let mut w = StateWriter::default();
        w.u32(7);
        w.u64(u64::MAX - 1);
        w.u128(1 << 100);
        w.f64(-0.25);
        w.bytes(b"abc");
        w.f32s(&[1.5, -2.0]);
        let bytes = w.finish();
        let mut r = StateReader::new(&bytes);
        assert_eq!(r.u32("a"), Ok(7));
        assert_eq!(r.u64("b"), Ok(u64::MAX - 1));
        assert_eq!(r.u128("c"), Ok(1 << 100));
        assert_eq!(r.f64("d"), Ok(-0.25));
        assert_eq!(r.bytes("e"), Ok(b"abc".to_vec()));
        assert_eq!(r.f32s("f"), Ok(vec![1.5, -2.0]));
        assert_eq!(r.end(), Ok(()));
        let mut cut = StateReader::new(&bytes[..bytes.len() - 3]);
        let _ = (cut.u32("a"), cut.u64("b"), cut.u128("c"), cut.f64("d"));
        assert_eq!(cut.bytes("e"), Ok(b"abc".to_vec()));
        assert!(cut.f32s("f").is_err(), "cut short");
        let mut huge = StateWriter::default();
        huge.u64(u64::MAX);
        assert!(StateReader::new(&huge.finish()).f32s("huge").is_err());
    }
}

//! The catalogue a recommender embedding was trained on, written after its snapshot bytes:
//! the Recommender refuses a snapshot of other items instead of mapping its rows to the
//! wrong ids. Slots never move and new items take free slots, so a catalogue that grew since
//! still matches: the tag holds how many items the trainer's catalogue held and a hash of
//! their ids in slot order, and the reader hashes as many of its own.
//!
//! The trailer is 32 bytes: items, capacity and the hash (little-endian `u64`s), then
//! [`MAGIC`]. Bytes without it (every other environment, and snapshots from before it) read
//! as untagged.

/// The trailer's last eight bytes.
pub const MAGIC: &[u8; 8] = b"JSAECAT1";
const TRAILER: usize = 32;

/// The catalogue an embedding snapshot's rows are of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CatalogueTag {
    /// Items the catalogue held (slots `0..items`).
    pub items: u64,
    /// Its slots, free ones included (the actions).
    pub capacity: u64,
    /// A hash of the ids of slots `0..items`, in slot order.
    pub prefix_hash: u64,
}

impl CatalogueTag {
    /// Appends the tag to snapshot bytes.
    pub fn append_to(&self, bytes: &mut Vec<u8>) {
        for v in [self.items, self.capacity, self.prefix_hash] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        bytes.extend_from_slice(MAGIC);
    }

    /// The tag at the end of `bytes`, if any, and the bytes before it.
    pub fn split(bytes: &[u8]) -> (Option<Self>, &[u8]) {
        if bytes.len() < TRAILER || !bytes.ends_with(MAGIC) {
            return (None, bytes);
        }
        let (model, trailer) = bytes.split_at(bytes.len() - TRAILER);
        let word = |i: usize| {
            let mut w = [0u8; 8];
            w.copy_from_slice(&trailer[i * 8..i * 8 + 8]);
            u64::from_le_bytes(w)
        };
        let tag = Self {
            items: word(0),
            capacity: word(1),
            prefix_hash: word(2),
        };
        (Some(tag), model)
    }

    /// Why a catalogue of `capacity` slots whose first `self.items` ids hash to `ours` (None:
    /// it holds fewer items than that, `held` of them) is not the one this tag names.
    pub fn mismatch(&self, capacity: u64, held: u64, ours: Option<u64>) -> Option<String> {
        if capacity != self.capacity {
            return Some(format!(
                "the snapshot was trained on a catalogue of {} slots, this one has {capacity} \
                 (environment.recommender.top_n)",
                self.capacity
            ));
        }
        match ours {
            Some(h) if h == self.prefix_hash => None,
            Some(_) => Some(format!(
                "the snapshot's first {} items are not this catalogue's (other data, another \
                 catalogue seed, or another session store)",
                self.items
            )),
            None => Some(format!(
                "the snapshot was trained on a catalogue of {} items, this one holds {held} \
                 (another session store, or one not read yet)",
                self.items
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tag_round_trips_and_untagged_bytes_stay_whole() {
        let tag = CatalogueTag {
            items: 7,
            capacity: 9,
            prefix_hash: 0xdead_beef,
        };
        let mut bytes = vec![1, 2, 3];
        tag.append_to(&mut bytes);
        assert_eq!(CatalogueTag::split(&bytes), (Some(tag), &[1u8, 2, 3][..]));
        let plain = vec![5u8; 40];
        assert_eq!(CatalogueTag::split(&plain), (None, &plain[..]));
        assert_eq!(tag.mismatch(9, 7, Some(0xdead_beef)), None);
        assert!(tag.mismatch(10, 7, Some(0xdead_beef)).is_some());
        assert!(tag.mismatch(9, 7, Some(1)).is_some());
        assert!(tag.mismatch(9, 3, None).is_some());
    }
}

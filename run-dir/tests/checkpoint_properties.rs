//! Property tests of the latest-checkpoint file: any bytes read back give an answer (never a
//! panic), a file reads back as written, and one with any one bit flipped is refused.

use jsae_run_dir::LatestCheckpoint;
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2_000))]

    #[test]
    fn arbitrary_bytes_never_panic_the_checkpoint_reader(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        let _ = LatestCheckpoint::decode(&bytes);
    }

    #[test]
    fn a_checkpoint_with_any_bit_flipped_is_refused(
        weights in prop::collection::vec(any::<u8>(), 0..256),
        state in prop::collection::vec(any::<u8>(), 0..256),
        version in any::<u64>(),
        flip in any::<prop::sample::Index>(),
        bit in 0u8..8,
    ) {
        let file = LatestCheckpoint { version, weights, state };
        let mut bytes = file.encode();
        prop_assert_eq!(LatestCheckpoint::decode(&bytes).ok(), Some(file));
        let i = flip.index(bytes.len());
        bytes[i] ^= 1 << bit;
        prop_assert!(LatestCheckpoint::decode(&bytes).is_err());
    }
}

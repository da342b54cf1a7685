//! Identifiers nobody can guess or derive from what they can see (an actor's incarnation, an
//! evaluation request): random nonzero numbers from a generator seeded by the operating
//! system.

/// A random nonzero `u64` (rand's thread generator: a cryptographically secure generator
/// seeded from the operating system's entropy).
pub fn random_id() -> u64 {
    loop {
        let id: u64 = rand::random();
        if id != 0 {
            return id;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_nonzero_and_differ() {
        let ids: std::collections::HashSet<u64> = (0..64).map(|_| random_id()).collect();
        assert_eq!(ids.len(), 64);
        assert!(!ids.contains(&0));
    }
}

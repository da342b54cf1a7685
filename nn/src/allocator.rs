//! The process's heap allocator: mimalloc, for every binary and test that links this crate.
//!
//! Training allocates and frees tensors of megabytes on every step (a `[512, 4,096]` batch of
//! logits is 8 MB). glibc's malloc serves blocks that large with `mmap` and returns them to
//! the kernel on `free`, so every step faulted in and zeroed fresh pages: on the AE baseline
//! at 4,096 gridworld actions, 18 of 47 s went to the kernel (page faults, zeroing, unmapping).
//! mimalloc keeps freed memory for reuse. Which allocator is used changes no number a run
//! computes, only where its buffers live.

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Hands the memory freed lately back to the kernel now. mimalloc keeps freed memory for reuse
/// and purges it later, when it next allocates; a process that has just dropped hundreds of
/// MB it will not need again (a million items' snapshot bytes once decoded) calls this, so
/// that what it allocates next does not stack on them in its peak.
pub fn release_freed() {
    // SAFETY: `mi_collect` takes no pointers and may be called from any thread at any time.
    #[allow(unsafe_code)]
    unsafe {
        libmimalloc_sys::mi_collect(true);
    }
}

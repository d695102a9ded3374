//! The allocator's thresholds for a process that runs the pipeline.
//!
//! glibc's malloc serves blocks above a *dynamic* threshold (128 KiB at start, rising to
//! at most 32 MiB as such blocks are freed) with their own `mmap` and gives them back to
//! the kernel on `free`. The pipeline allocates columns of a few to a few tens of MiB for
//! every chunk of a drive; each time, the kernel maps and zeroes fresh pages for them.
//! On the 1 km bench drive that was ~780 000 page faults and 3 s of system time against
//! 10 s of user time. With the threshold pinned at its maximum and the heap trimmed only
//! when 512 MiB lie free at its top, the freed blocks are reused: ~550 000 faults, about
//! half the system time, and a lower peak (fewer half-used mappings).
//!
//! Written here: a two-call policy over `mallopt`, which no allocator crate sets for
//! glibc (a replacement allocator was measured and did worse: jemalloc 1.1–1.7 M faults,
//! mimalloc more system time from huge-page faults).

/// `M_MMAP_THRESHOLD` (bytes): the dynamic threshold's ceiling on 64-bit targets.
pub const MMAP_THRESHOLD: usize = 32 << 20;
/// Free memory at the top of the heap above which glibc gives it back (bytes).
pub const TRIM_THRESHOLD: usize = 512 << 20;

/// Pin glibc's malloc thresholds (see the module docs). Returns whether both settings
/// were taken; elsewhere (another C library, another OS) nothing is done and it is false.
pub fn tune_allocator() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only sets allocator parameters; it is called with documented
        // parameter numbers and values within their ranges, before any thread starts.
        unsafe {
            let mmap = libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD as libc::c_int);
            let trim = libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD as libc::c_int);
            mmap == 1 && trim == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// glibc takes both values (`mallopt` returns 0 for a value it refuses and keeps its
    /// default then, as it did for a threshold written out of `c_int` range).
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_takes_the_thresholds() {
        assert!(tune_allocator());
    }
}

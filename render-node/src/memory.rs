//! What a render node's scene costs in memory, read from the process itself: resident bytes
//! from `/proc/self/statm`, and glibc asked to hand freed heap back first, so that what the
//! loader and the BVH build used and dropped is not counted as the scene's.

/// Resident bytes of this process, or `None` where `/proc` has no answer (not Linux).
pub fn resident_bytes() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    // SAFETY: sysconf has no preconditions.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    Some(pages * u64::try_from(page).ok()?)
}

/// Memory the system could give this process now without swapping (`MemAvailable` of
/// `/proc/meminfo`), or `None` where `/proc` has no answer.
pub fn available_bytes() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// The most resident bytes this process has had (`VmHWM`), or `None` where `/proc` has no
/// answer.
pub fn peak_resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// Returns freed heap memory to the system. glibc keeps freed blocks below its (growing) mmap
/// threshold in the heap, so without this a node would hold on to its loader's peak.
pub fn release_freed() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only walks glibc's own arenas.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Makes every allocation of 16 MiB or more a mapping of its own. glibc otherwise raises its
/// mmap threshold as large blocks are freed (up to 32 MiB), so a loader's arrays land in the
/// heap, and what is allocated after them pins their pages: a freed scene stayed resident or
/// not depending on the order of allocations (61.7 or 69.2 B/tri for the same knot). Own
/// mappings go back to the system the moment they are freed.
pub fn map_large_allocations() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets a glibc tuning value.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 16 << 20);
    }
}

/// Keeps glibc to two heaps (arenas). By default it makes one per thread that contends, up to
/// eight per core, and each keeps what its thread freed: a shared scene's fetched blocks, 8 KB
/// each, are allocated on the network threads and freed on the render threads when the cache
/// lets them go, and with an arena per thread a node held 45 MiB above its blocks instead of
/// 20 (a 272 MiB budget, 4 nodes, the 16.8M-triangle knot).
pub fn few_heaps() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets a glibc tuning value.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 2);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_touched_allocation_shows_in_resident_memory() {
        let Some(before) = resident_bytes() else {
            return; // no /proc here
        };
        let block = vec![1u8; 64 << 20];
        let during = resident_bytes().unwrap();
        assert!(during >= before + (60 << 20), "{before} -> {during}");
        assert!(peak_resident_bytes().unwrap() >= during);
        drop(std::hint::black_box(block));
        release_freed();
    }
}

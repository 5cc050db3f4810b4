//! Memory for large scenes: large blocks in mappings of their own, and the arrays rays read
//! at random on huge pages.
//!
//! [`LargeBlocks`] is a global allocator that maps each block of at least [`LARGE`] bytes
//! itself (grown and shrunk by `mremap`, returned to the kernel when freed) and passes smaller
//! ones to the system allocator. glibc's `malloc` raises its mapping threshold after the first
//! large block is freed, and then serves big vectors from its heap, where growth copies them
//! and freed space stays resident: loading and building a 4 M-triangle scene peaked at 152
//! bytes per triangle through glibc and at about 133 through `LargeBlocks`.
//!
//! [`huge_vec`] and [`advise_huge`] mark an array that is about to be filled for transparent
//! huge pages (`MADV_HUGEPAGE`). A million-triangle scene's BVH nodes, packed triangles and
//! shading records are tens of megabytes read at random places by every ray, and with 4 KiB
//! pages each read can also miss the TLB (a 2-core EPYC's second-level TLB covers 12 MiB of
//! 4 KiB pages, 6 GiB of 2 MiB ones); many kernels give huge pages only where asked
//! (`/sys/kernel/mm/transparent_hugepage/enabled` reads `madvise`). The scene builder marks
//! its render-time arrays (nodes, packed triangles, primitives, shading records, vertex
//! positions and normals) and nothing else, so its temporaries fault in as before. On a 2-core
//! AMD EPYC (Zen 4, a virtual machine; 2026-12-03) this made rendering the 1 M-triangle
//! bumpy-sphere scene 6-8 % faster and building a 4 M-triangle one about 0.1-0.4 s slower;
//! moving the finished arrays instead (`MADV_COLLAPSE`) cost 0.7-1.2 s there. Where the
//! kernel refuses (huge pages `never`, not Linux) nothing changes; `never` is also how an
//! administrator turns this off. Memory layout never changes a pixel: the renderer's
//! arithmetic does not depend on addresses.
//!
//! The binaries opt in with
//! `#[global_allocator] static ALLOC: raytile_core::alloc::LargeBlocks = raytile_core::alloc::LargeBlocks;`.

use std::alloc::{GlobalAlloc, Layout, System};

/// Blocks of at least this many bytes get a mapping of their own.
pub const LARGE: usize = 2 << 20;

/// The allocator: [`System`] for small blocks, anonymous mappings for large ones.
#[derive(Clone, Copy, Debug, Default)]
pub struct LargeBlocks;

/// The transparent huge page size on x86-64 and most Linux targets.
const HUGE_PAGE: usize = 2 << 20;

/// An empty vector with room for `n` elements whose whole huge pages are marked for
/// transparent huge pages before anything is written to them: for arrays that rays read at
/// random. Fill it with `push`, `extend` or rayon's `par_extend` up to `n`.
pub fn huge_vec<T>(n: usize) -> Vec<T> {
    let v: Vec<T> = Vec::with_capacity(n);
    advise(
        v.as_ptr().cast(),
        n.saturating_mul(std::mem::size_of::<T>()),
    );
    v
}

/// Marks the whole huge pages inside `data` for transparent huge pages (`MADV_HUGEPAGE`):
/// pages not touched yet (a zeroed vector just allocated, say) then fault in 2 MiB at a time.
pub fn advise_huge<T>(data: &[T]) {
    advise(data.as_ptr().cast(), std::mem::size_of_val(data));
}

fn advise(p: *const u8, len: usize) {
    let start = p as usize;
    let (lo, hi) = (
        start.next_multiple_of(HUGE_PAGE),
        start.saturating_add(len) / HUGE_PAGE * HUGE_PAGE,
    );
    if hi <= lo {
        return;
    }
    #[cfg(target_os = "linux")]
    // SAFETY: `lo..hi` lies inside memory of the caller's; the advice only changes how its
    // pages fault in (an error, such as EINVAL where huge pages are compiled out, changes
    // nothing).
    unsafe {
        libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_HUGEPAGE);
    }
}

#[cfg(target_os = "linux")]
mod imp {
    use super::LARGE;
    use std::alloc::Layout;

    /// mmap's granule; a block asking for larger alignment stays with the system allocator.
    const PAGE: usize = 4096;

    /// Whether `layout` is served by its own mapping.
    #[inline]
    pub fn own_mapping(layout: &Layout) -> bool {
        layout.size() >= LARGE && layout.align() <= PAGE
    }

    /// A new zeroed mapping of `size` bytes (null on failure).
    pub fn map(size: usize) -> *mut u8 {
        // SAFETY: an anonymous private mapping at an address of the kernel's choice touches no
        // existing memory.
        let p = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                size,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                -1,
                0,
            )
        };
        if p == libc::MAP_FAILED {
            return std::ptr::null_mut();
        }
        p.cast()
    }

    /// Unmaps a block from [`map`] or [`remap`].
    pub fn unmap(p: *mut u8, size: usize) {
        // SAFETY: `p` was mapped by `map`/`remap` with this size, and the caller gives it up.
        unsafe { libc::munmap(p.cast(), size) };
    }

    /// Grows or shrinks a block from [`map`]: the kernel moves the pages, nothing is copied.
    pub fn remap(p: *mut u8, old: usize, new: usize) -> *mut u8 {
        // SAFETY: `p` is a mapping of `old` bytes of ours; on success it is replaced by the
        // returned mapping, on failure it is left as it was.
        let q = unsafe { libc::mremap(p.cast(), old, new, libc::MREMAP_MAYMOVE) };
        if q == libc::MAP_FAILED {
            return std::ptr::null_mut();
        }
        q.cast()
    }
}

// SAFETY: every block is either the system allocator's (small layouts, passed through) or a
// mapping of its own of at least `layout.size()` bytes, page-aligned (which satisfies every
// alignment up to a page, the only ones routed there); which of the two a block is follows
// from its layout alone, which the caller must pass back unchanged, and `realloc` moves a
// block between the two kinds when its size crosses the threshold.
unsafe impl GlobalAlloc for LargeBlocks {
    #[inline]
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        #[cfg(target_os = "linux")]
        if imp::own_mapping(&layout) {
            return imp::map(layout.size());
        }
        // SAFETY: the caller's contract is passed on.
        unsafe { System.alloc(layout) }
    }

    #[inline]
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        #[cfg(target_os = "linux")]
        if imp::own_mapping(&layout) {
            return imp::map(layout.size()); // fresh anonymous pages are zero
        }
        // SAFETY: the caller's contract is passed on.
        unsafe { System.alloc_zeroed(layout) }
    }

    #[inline]
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        #[cfg(target_os = "linux")]
        if imp::own_mapping(&layout) {
            return imp::unmap(ptr, layout.size());
        }
        // SAFETY: the caller's contract is passed on.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        #[cfg(target_os = "linux")]
        {
            // SAFETY: the caller guarantees `new_size` with `layout.align()` is a valid layout.
            let new = unsafe { Layout::from_size_align_unchecked(new_size, layout.align()) };
            match (imp::own_mapping(&layout), imp::own_mapping(&new)) {
                (true, true) => return imp::remap(ptr, layout.size(), new_size),
                (false, false) => {}
                _ => {
                    // Crossing the threshold: a block of the other kind, and a copy.
                    // SAFETY: `new` is valid (above); `ptr` holds `layout.size()` bytes.
                    let q = unsafe { self.alloc(new) };
                    if !q.is_null() {
                        let n = layout.size().min(new_size);
                        // SAFETY: both blocks hold at least `n` bytes and do not overlap.
                        unsafe {
                            std::ptr::copy_nonoverlapping(ptr, q, n);
                            self.dealloc(ptr, layout);
                        }
                    }
                    return q;
                }
            }
        }
        // SAFETY: the caller's contract is passed on.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Blocks on both sides of the threshold keep their bytes through growth and shrinking
    /// across it, and large ones come back zeroed and page-aligned.
    #[test]
    fn blocks_keep_their_bytes_across_the_threshold() {
        let a = LargeBlocks;
        let sizes = [64, LARGE - 8, LARGE, 3 * LARGE + 100, 1000, 5 * LARGE];
        unsafe {
            let layout = Layout::from_size_align(sizes[0], 8).unwrap();
            let mut p = a.alloc(layout);
            let mut size = sizes[0];
            let fill = |p: *mut u8, n: usize| {
                for i in 0..n {
                    *p.add(i) = (i % 251) as u8;
                }
            };
            fill(p, size);
            for &next in &sizes[1..] {
                p = a.realloc(p, Layout::from_size_align(size, 8).unwrap(), next);
                assert!(!p.is_null());
                let kept = size.min(next);
                assert!(
                    (0..kept).all(|i| *p.add(i) == (i % 251) as u8),
                    "{size} -> {next}"
                );
                size = next;
                fill(p, size);
            }
            a.dealloc(p, Layout::from_size_align(size, 8).unwrap());

            let big = Layout::from_size_align(LARGE + 1, 64).unwrap();
            let z = a.alloc_zeroed(big);
            assert_eq!(z as usize % 64, 0);
            assert!((0..big.size()).all(|i| *z.add(i) == 0));
            a.dealloc(z, big);
        }
    }

    /// Advised vectors hold what is written to them, whatever the kernel does with the advice.
    #[test]
    fn advised_vectors_keep_their_contents() {
        let n = 3 * HUGE_PAGE / 4;
        let mut v: Vec<u32> = huge_vec(n);
        assert!(v.capacity() >= n);
        v.extend(0..n as u32);
        assert!(v.iter().enumerate().all(|(i, &x)| x == i as u32));
        let z = vec![0u64; n];
        advise_huge(&z);
        assert!(z.iter().all(|&x| x == 0));
        advise_huge::<u8>(&[]);
        assert!(huge_vec::<u8>(0).is_empty());
    }
}

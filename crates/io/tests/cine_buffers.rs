//! The cine reader reuses its buffers across frames: between one frame handed over and the
//! next, the only allocation is the next frame's image. A counting allocator (this test
//! binary's own) measures it on the 16-bit fixture of four 32 × 24 frames.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;

use fluidnerf_io::video::{read_video_frames, VideoOptions};

struct Counting;

thread_local! {
    /// Allocations made on this thread so far.
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: every call is forwarded unchanged to the system allocator; counting touches only a
// thread-local `Cell`, which does not allocate.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        // SAFETY: the caller's contract is the system allocator's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        // SAFETY: as above.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        // SAFETY: as above.
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn allocations() -> usize {
    ALLOCATIONS.with(Cell::get)
}

#[test]
fn frames_after_the_first_allocate_only_their_image() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/video/ramp_16bit.cine");
    // Allocations between the end of one frame's callback and the start of the next's.
    let mut between = Vec::new();
    let mut since: Option<usize> = None;
    let info = read_video_frames(&path, &VideoOptions::default(), |frame| {
        let now = allocations();
        if let Some(then) = since {
            between.push(now - then);
        }
        drop(frame);
        since = Some(allocations());
        Ok(())
    })
    .expect("reads");
    assert_eq!(info.frames_kept, 4);
    assert_eq!(between.len(), 3);
    assert!(between.iter().all(|&n| n == 1), "allocations per frame after the first: {between:?}");
}

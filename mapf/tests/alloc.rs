//! A tick of the resolver allocates nothing after `World::new` (the look-ahead replans
//! included); only the complete fallback search, which runs when the fleet stalls, may.

use mapf::{Instance, Intent, World, WorldConfig};
use planner::{Cell, Grid};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell as Flag;
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;

thread_local! {
    /// Counting is on for this thread only: the test harness's own threads may allocate.
    static COUNTING: Flag<bool> = const { Flag::new(false) };
}
static ALLOCS: AtomicUsize = AtomicUsize::new(0);

fn counting() -> bool {
    COUNTING.try_with(Flag::get).unwrap_or(false)
}

// SAFETY: forwards to the system allocator, only counting calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if counting() {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: the caller's contract is passed on unchanged.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract is passed on unchanged.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if counting() {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: the caller's contract is passed on unchanged.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn steps_allocate_nothing() {
    // the counter sees an allocation on this thread
    COUNTING.with(|c| c.set(true));
    let v = std::hint::black_box(vec![1u8; 16]);
    COUNTING.with(|c| c.set(false));
    assert!(ALLOCS.swap(0, Ordering::Relaxed) >= 1 && v.len() == 16);

    // a 20x20 room with a wall across the middle (one door) and 40 agents crossing it
    let (w, h) = (20usize, 20usize);
    let mut free = vec![true; w * h];
    for x in 0..w {
        if x != 10 {
            free[10 * w + x] = false;
        }
    }
    let grid = Grid::new(w, h, free).unwrap();
    let starts: Vec<Cell> = (0..40)
        .map(|i| Cell::new((i % 20) as u16, (i / 20) as u16))
        .collect();
    let goals: Vec<Cell> = (0..40)
        .map(|i| Cell::new((19 - i % 20) as u16, (19 - i / 20) as u16))
        .collect();
    let inst = Instance::new(grid, starts, goals).unwrap();
    let config = WorldConfig {
        record: false,
        ..WorldConfig::default()
    };
    let mut world = World::new(&inst, config);
    let mut intents = vec![None; inst.agents()];
    let mut allocs = 0;
    while world.tick() < 400 && !world.all_arrived() {
        for (i, p) in world.positions().iter().enumerate() {
            intents[i] = p.map(|c| Intent::toward(inst.grid(), inst.dist(i).unwrap(), c));
        }
        ALLOCS.store(0, Ordering::Relaxed);
        COUNTING.with(|c| c.set(true));
        let searches = world.searches();
        let r = world.step(&intents);
        COUNTING.with(|c| c.set(false));
        r.unwrap();
        if world.searches() == searches {
            allocs += ALLOCS.load(Ordering::Relaxed);
        }
    }
    assert!(world.all_arrived());
    assert!(
        world.replans() > 1,
        "the look-ahead was recomputed on the way"
    );
    assert_eq!(allocs, 0, "allocations during steps");
}

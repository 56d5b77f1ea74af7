//! Two-way fork–join on one persistent helper thread that spins between jobs.
//!
//! The active-set solver splits its sparse factorizations and triangular solves into two
//! uncoupled halves (a nested dissection's top level) that run at once, then the
//! separator alone. A solve takes 20–35 µs at n_h = 40, so the hand-off has to cost far
//! less than a thread spawn (38–54 µs on the benchmark's VM) or a wake-up from sleep
//! (50–150 µs measured for rayon's idle pool there). The helper therefore spins on an
//! atomic slot while jobs keep coming ([`SPIN`] after the last one, or after
//! [`warm`]), about 0.1 µs per hand-off, and parks otherwise.
//!
//! [`join`] runs one closure on the helper and the other on the caller and returns when
//! both are done. It falls back to running both on the caller when the machine has one
//! core, when the helper is busy with another caller's job (no caller ever waits for
//! another), from the helper thread itself, and in a forked child process (which has no
//! helper thread).

use std::any::Any;
use std::panic::{self, AssertUnwindSafe};
use std::ptr;
use std::sync::atomic::{AtomicBool, AtomicPtr, Ordering::*};
use std::sync::OnceLock;
use std::thread::{self, Thread};
use std::time::{Duration, Instant};

/// How long the helper spins after its last job (or a [`warm`]) before it parks.
const SPIN: Duration = Duration::from_micros(300);

/// A job on the caller's stack: the closure to run once and, afterwards, its panic.
struct Job<'a> {
    run: &'a mut (dyn FnMut() + Send),
    panic: Option<Box<dyn Any + Send>>,
}

struct Helper {
    /// The job to run next (null: none), published by the caller that holds `busy`.
    slot: AtomicPtr<Job<'static>>,
    /// Set by the helper when the published job has finished.
    done: AtomicBool,
    /// Held by the caller whose job the helper runs (or is about to).
    busy: AtomicBool,
    /// Set by the helper before it parks.
    parked: AtomicBool,
    /// Spin again (a [`warm`] call): the next jobs are near.
    nudge: AtomicBool,
    thread: Thread,
    pid: u32,
}

static HELPER: OnceLock<Option<&'static Helper>> = OnceLock::new();

fn helper() -> Option<&'static Helper> {
    let h = *HELPER.get_or_init(|| {
        if thread::available_parallelism().map_or(1, |n| n.get()) < 2 {
            return None;
        }
        let (tx, rx) = std::sync::mpsc::channel::<&'static Helper>();
        let spawned = thread::Builder::new().name("preisach-helper".into()).spawn(move || {
            let Ok(h) = rx.recv() else { return };
            h.serve();
        });
        let Ok(handle) = spawned else { return None };
        let h: &'static Helper = Box::leak(Box::new(Helper {
            slot: AtomicPtr::new(ptr::null_mut()),
            done: AtomicBool::new(false),
            busy: AtomicBool::new(false),
            parked: AtomicBool::new(false),
            nudge: AtomicBool::new(false),
            thread: handle.thread().clone(),
            pid: std::process::id(),
        }));
        tx.send(h).ok()?;
        Some(h)
    });
    // A forked child inherits the static but not the thread.
    h.filter(|h| h.pid == std::process::id() && thread::current().id() != h.thread.id())
}

impl Helper {
    fn serve(&self) {
        let mut last = Instant::now();
        let mut spins = 0u32;
        loop {
            // Read-only polling (a swap would take the cache line from the caller).
            let p = if self.slot.load(Relaxed).is_null() { ptr::null_mut() } else { self.slot.swap(ptr::null_mut(), Acquire) };
            if !p.is_null() {
                // SAFETY: `join` published a pointer to a `Job` on its stack and does not
                // return (nor unwind) before it sees `done`, so the job and everything
                // its closure borrows outlive this use; no one else touches the job
                // until then.
                let job = unsafe { &mut *p };
                if let Err(e) = panic::catch_unwind(AssertUnwindSafe(|| (job.run)())) {
                    job.panic = Some(e);
                }
                self.done.store(true, Release);
                last = Instant::now();
                continue;
            }
            if self.nudge.load(Relaxed) {
                self.nudge.store(false, Relaxed);
                last = Instant::now();
            }
            spins = spins.wrapping_add(1);
            if spins % 64 != 0 || last.elapsed() < SPIN {
                for _ in 0..8 {
                    std::hint::spin_loop();
                }
                continue;
            }
            // Park; a job published after `parked` is set finds it and unparks (the
            // stores and loads on both sides are sequentially consistent, so at least
            // one side sees the other's).
            self.parked.store(true, SeqCst);
            if self.slot.load(SeqCst).is_null() && !self.nudge.load(SeqCst) {
                thread::park();
            }
            self.parked.store(false, SeqCst);
            last = Instant::now();
        }
    }

    fn wake(&self) {
        if self.parked.load(SeqCst) {
            self.thread.unpark();
        }
    }
}

/// Start the helper spinning (if idle): the caller's first [`join`] follows soon, and a
/// parked thread takes tens of microseconds to wake.
pub fn warm() {
    if let Some(h) = helper() {
        h.nudge.store(true, SeqCst);
        h.wake();
    }
}

/// Run `a` and `b` at once, `a` on the helper thread and `b` on the caller, and return
/// when both have finished; both on the caller if the helper is unavailable (see the
/// module documentation). A panic in either is resumed on the caller after both ended.
pub fn join<A: FnOnce() + Send, B: FnOnce()>(a: A, b: B) {
    let Some(h) = helper() else {
        a();
        b();
        return;
    };
    if h.busy.compare_exchange(false, true, Acquire, Relaxed).is_err() {
        a();
        b();
        return;
    }
    let mut a = Some(a);
    let mut run = move || {
        if let Some(a) = a.take() {
            a();
        }
    };
    let mut job = Job { run: &mut run, panic: None };
    h.done.store(false, Relaxed);
    // SAFETY: only the lifetime is erased; the helper uses the pointer before `done` is
    // set, and this function waits for `done` below on every path (a panic in `b` is
    // caught first), so the job outlives every use.
    let p: *mut Job<'static> = &mut job as *mut Job<'_> as *mut _;
    h.slot.store(p, SeqCst);
    h.wake();
    let rb = panic::catch_unwind(AssertUnwindSafe(b));
    while !h.done.load(Acquire) {
        std::hint::spin_loop();
    }
    h.busy.store(false, Release);
    if let Some(e) = job.panic.take() {
        panic::resume_unwind(e);
    }
    if let Err(e) = rb {
        panic::resume_unwind(e);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_halves_run_and_write_their_own_data() {
        let mut left = vec![0u64; 1000];
        let mut right = vec![0u64; 1000];
        for round in 0..200u64 {
            join(
                || left.iter_mut().enumerate().for_each(|(i, x)| *x = i as u64 * round),
                || right.iter_mut().enumerate().for_each(|(i, x)| *x = i as u64 + round),
            );
            assert_eq!(left[999], 999 * round);
            assert_eq!(right[999], 999 + round);
        }
    }

    #[test]
    fn concurrent_callers_and_nested_joins_do_not_deadlock() {
        let total = std::sync::atomic::AtomicU64::new(0);
        thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| {
                    for _ in 0..500 {
                        join(
                            || {
                                join(|| _ = total.fetch_add(1, Relaxed), || _ = total.fetch_add(1, Relaxed));
                            },
                            || _ = total.fetch_add(1, Relaxed),
                        );
                    }
                });
            }
        });
        assert_eq!(total.load(Relaxed), 4 * 500 * 3);
    }

    #[test]
    fn a_panic_on_either_side_reaches_the_caller_after_both_ended() {
        for side in 0..2 {
            let mut other_ran = false;
            let r = panic::catch_unwind(AssertUnwindSafe(|| {
                join(
                    || {
                        if side == 0 {
                            panic!("left");
                        }
                    },
                    || {
                        if side == 1 {
                            panic!("right");
                        }
                    },
                );
            }));
            assert!(r.is_err());
            // The helper is free again.
            join(|| other_ran = true, || ());
            assert!(other_ran);
        }
    }
}

//! Two-way fork–join on one persistent helper thread that spins between jobs.
//!
//! The active-set solver splits its sparse factorizations and triangular solves into two
//! uncoupled halves (a nested dissection's top level) that run at once, then the
//! separator alone. A solve takes 20–35 µs at n_h = 40, so the hand-off has to cost far
//! less than a thread spawn (38–54 µs on the benchmark's VM) or a wake-up from sleep
//! (50–150 µs measured for rayon's idle pool there). The helper therefore spins on an
//! atomic slot while a [`Session`] (one fit) is open, about 0.1 µs per hand-off, and
//! parks otherwise.
//!
//! [`join`] runs one closure on the helper and the other on the caller and returns when
//! both are done. If the helper has not taken its job by the time the caller's closure
//! ends, the caller takes it back and runs it itself: no caller waits for a thread that
//! is not running. It runs both on the caller when the machine has one core or
//! `PREISACH_NUM_THREADS=1` is set (read once), while more than one session is open in
//! the process (concurrent solves already keep the cores busy: measured with two Python
//! threads fitting at once, the helper halved their throughput before this rule), when
//! the helper is busy with another caller's job, from the helper thread itself, and in a
//! forked child process (which has no helper thread).

use std::any::Any;
use std::cell::Cell;
use std::panic::{self, AssertUnwindSafe};
use std::ptr;
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicUsize, Ordering::*};
use std::sync::OnceLock;
use std::thread::{self, Thread};
use std::time::{Duration, Instant};

/// How long the helper spins after its last job (or the last [`session`] call) before it
/// parks, while one session is open: long enough to span the row building between a
/// fit's start and its solve's first split factorization (1 ms at n_h = 40).
const SPIN: Duration = Duration::from_millis(2);

/// Sessions open in the process.
static ACTIVE: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    /// Sessions open on this thread (nested ones count once in [`ACTIVE`]).
    static DEPTH: Cell<u32> = const { Cell::new(0) };
}

/// A stretch of work that will call [`join`] often (one fit): while exactly one is open
/// in the process the helper spins between jobs. Close it by dropping it; sessions nest.
pub struct Session(());

/// Open a [`Session`] and start the helper spinning: a parked thread takes tens of
/// microseconds (on the benchmark's VM at times over a millisecond) to wake, so open it
/// ahead of the first [`join`].
pub fn session() -> Session {
    let outer = DEPTH.with(|d| {
        d.set(d.get() + 1);
        d.get() == 1
    });
    if outer {
        ACTIVE.fetch_add(1, SeqCst);
    }
    if ACTIVE.load(SeqCst) == 1 {
        if let Some(h) = helper() {
            h.nudge.store(true, SeqCst);
            h.wake();
        }
    }
    Session(())
}

impl Drop for Session {
    fn drop(&mut self) {
        let outer = DEPTH.with(|d| {
            d.set(d.get() - 1);
            d.get() == 0
        });
        if outer {
            ACTIVE.fetch_sub(1, SeqCst);
        }
    }
}

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
    /// Spin again (a [`session`] call): the next jobs are near.
    nudge: AtomicBool,
    thread: Thread,
    pid: u32,
}

static HELPER: OnceLock<Option<&'static Helper>> = OnceLock::new();

/// Threads to use: `PREISACH_NUM_THREADS` if set to a positive number (1: no helper
/// thread, everything on the caller's), else the available parallelism.
fn threads() -> usize {
    match std::env::var("PREISACH_NUM_THREADS").ok().and_then(|v| v.trim().parse::<usize>().ok()) {
        Some(n) if n > 0 => n,
        _ => thread::available_parallelism().map_or(1, |n| n.get()),
    }
}

fn helper() -> Option<&'static Helper> {
    let h = *HELPER.get_or_init(|| {
        if threads() < 2 {
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
            let p = if self.slot.load(Relaxed).is_null() {
                ptr::null_mut()
            } else {
                self.slot.swap(ptr::null_mut(), Acquire)
            };
            if !p.is_null() {
                // SAFETY: `join` published a pointer to a `Job` on its stack; once this
                // swap has taken it, `join` can no longer take it back and does not
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
            if spins % 64 != 0 || (ACTIVE.load(Relaxed) == 1 && last.elapsed() < SPIN) {
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

/// Whether a [`join`] now would run on two threads (as far as can be told before: the
/// helper may still be taken by another caller in between).
pub fn available() -> bool {
    ACTIVE.load(Relaxed) <= 1 && helper().is_some_and(|h| !h.busy.load(Relaxed))
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
    if ACTIVE.load(Relaxed) > 1 || h.busy.compare_exchange(false, true, Acquire, Relaxed).is_err() {
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
    // SAFETY: only the lifetime is erased. The helper uses the pointer only if its swap
    // takes it from the slot, and then before it sets `done`; this function either takes
    // the pointer back itself (so the helper never will) or waits for `done`, on every
    // path (a panic in `b` is caught first). So the job outlives every use.
    let p: *mut Job<'static> = &mut job as *mut Job<'_> as *mut _;
    h.slot.store(p, SeqCst);
    h.wake();
    let rb = panic::catch_unwind(AssertUnwindSafe(b));
    if h.slot.compare_exchange(p, ptr::null_mut(), AcqRel, Relaxed).is_ok() {
        // Not taken yet (the helper is parked or not running): run it here.
        if let Err(e) = panic::catch_unwind(AssertUnwindSafe(|| (job.run)())) {
            job.panic = Some(e);
        }
    } else {
        let mut spins = 0u32;
        while !h.done.load(Acquire) {
            spins = spins.wrapping_add(1);
            if spins % 4096 == 0 {
                // (The helper was descheduled mid-job: let it run.)
                thread::yield_now();
            } else {
                std::hint::spin_loop();
            }
        }
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
    fn within_a_session_the_helper_takes_the_other_half() {
        if helper().is_none() {
            return; // one core (or PREISACH_NUM_THREADS=1): everything runs on the caller
        }
        let _s = session();
        let me = thread::current().id();
        let mut elsewhere = 0;
        // (Other tests may hold the helper for a while: a panic there prints a backtrace.)
        for _ in 0..5000 {
            if elsewhere == 50 {
                break;
            }
            let mut ran = None;
            join(
                || ran = Some(thread::current().id()),
                || {
                    let t = Instant::now();
                    while t.elapsed() < Duration::from_micros(200) {
                        std::hint::spin_loop();
                    }
                },
            );
            assert!(ran.is_some());
            elsewhere += usize::from(ran != Some(me));
        }
        assert_eq!(elsewhere, 50, "the helper ran {elsewhere} of 5000 halves");
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

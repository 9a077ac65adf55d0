//! Thread priority of the analysis: a thread that consumes decoded frames (the preparer, the
//! pump with its flows, the sharpness worker) and finds that it mostly waits for its producer
//! lowers its own priority, so that on a machine with fewer cores than busy threads the decoder,
//! then the pipeline's slowest stage, is not the one kept waiting; a consumer that is itself the
//! slowest stage (the stationary step's flows) keeps its priority. Lowering a thread's own
//! priority needs no privilege and changes no result; it cannot be undone without privilege, so
//! each thread decides once, after a warm-up. Threads only ever lower themselves: what they
//! spawn afterwards inherits it, and the main thread is never lowered.

use std::sync::mpsc::{Receiver, RecvError, TryRecvError};

/// Items a consumer receives before it starts counting (the decoder's start-up).
const WARM_UP: u32 = 16;
/// Items counted before the decision.
const WINDOW: u32 = 48;

/// A consumer's receiving end of its input queue: counts how often an item was not there yet
/// and, once [`WINDOW`] items after the [`WARM_UP`] have been counted, lowers the calling thread
/// when it waited for at least half of them.
pub(crate) struct Consumer {
    stage: &'static str,
    seen: u32,
    waits: u32,
    decided: bool,
}

impl Consumer {
    pub(crate) fn new(stage: &'static str) -> Consumer {
        Consumer {
            stage,
            seen: 0,
            waits: 0,
            decided: false,
        }
    }

    /// The next item of `rx` (blocking), as `Receiver::recv`.
    pub(crate) fn recv<T>(&mut self, rx: &Receiver<T>) -> Result<T, RecvError> {
        match rx.try_recv() {
            Ok(item) => {
                self.note(false);
                Ok(item)
            }
            Err(TryRecvError::Empty) => {
                self.note(true);
                rx.recv()
            }
            Err(TryRecvError::Disconnected) => Err(RecvError),
        }
    }

    fn note(&mut self, waited: bool) {
        if self.decided {
            return;
        }
        self.seen += 1;
        if self.seen <= WARM_UP {
            return;
        }
        self.waits += u32::from(waited);
        if self.seen - WARM_UP < WINDOW {
            return;
        }
        self.decided = true;
        let lower = waits_mostly(self.waits, WINDOW);
        log::debug!(
            "analysis {}: waited for {} of {WINDOW} frames: {}",
            self.stage,
            self.waits,
            if lower {
                "its producer is the slower stage, lowering its priority"
            } else {
                "it is the slower stage, keeping its priority"
            }
        );
        if lower {
            lower_this_thread();
        }
    }
}

/// Whether a consumer that waited `waits` times in `window` items mostly waits.
fn waits_mostly(waits: u32, window: u32) -> bool {
    2 * waits >= window
}

/// The nice value the consuming threads take (Linux: 0 is the default, 19 the lowest; see
/// docs/benchmarks.md for the values measured).
pub(crate) const ANALYSIS_NICE: i32 = 5;

/// Lowers the calling thread (only it: Linux keeps a nice value per thread) to
/// [`ANALYSIS_NICE`], unless `KEYFRAMER_ANALYSIS_NICE` gives another value (0 keeps the
/// priority); never raises it (a `nice -n 15 keyframer ...` stays at 15, even as root). A
/// failure only costs speed: it is logged at debug level.
pub(crate) fn lower_this_thread() {
    let nice = target();
    if nice > own_nice() {
        set_nice(nice);
    }
}

/// The nice value asked for: `KEYFRAMER_ANALYSIS_NICE` (0 to 19) or [`ANALYSIS_NICE`].
fn target() -> i32 {
    match std::env::var("KEYFRAMER_ANALYSIS_NICE") {
        Ok(v) => match v.trim().parse::<i32>() {
            Ok(n) => n.clamp(0, 19),
            Err(_) => {
                log::warn!("KEYFRAMER_ANALYSIS_NICE={v:?} is not a number from 0 to 19; ignored");
                ANALYSIS_NICE
            }
        },
        Err(_) => ANALYSIS_NICE,
    }
}

#[cfg(target_os = "linux")]
fn set_nice(nice: i32) {
    // SAFETY: two plain system calls on the calling thread's own id; no memory is passed.
    let ok = unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        libc::setpriority(libc::PRIO_PROCESS, tid, nice) == 0
    };
    if !ok {
        let e = std::io::Error::last_os_error();
        log::debug!("could not lower the analysis thread's priority to nice {nice}: {e}");
    }
}

/// The calling thread's nice value (0 where it cannot be read).
#[cfg(target_os = "linux")]
fn own_nice() -> i32 {
    // SAFETY: as in `set_nice`. getpriority returns the nice value itself (-20 to 19), and -1
    // with errno set on failure, which only a bad thread id gives; ours is valid.
    unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        libc::getpriority(libc::PRIO_PROCESS, tid)
    }
}

#[cfg(not(target_os = "linux"))]
fn set_nice(_nice: i32) {}

#[cfg(not(target_os = "linux"))]
fn own_nice() -> i32 {
    0
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn a_consumer_that_mostly_waits_is_lowered_once_after_the_warm_up() {
        assert!(waits_mostly(24, 48));
        assert!(!waits_mostly(23, 48));
        // The count, fed directly (no timing): the nice value after each item.
        let run = |waited: fn(u32) -> bool| {
            std::thread::spawn(move || {
                let mut c = Consumer::new("test");
                (0..WARM_UP + WINDOW + 8)
                    .map(|k| {
                        c.note(waited(k));
                        own_nice()
                    })
                    .collect::<Vec<_>>()
            })
            .join()
            .unwrap()
        };
        let before = own_nice();
        let lowered = target().max(before);
        // Waits for every item: lowered with the window's last item, not before.
        for (k, n) in run(|_| true).into_iter().enumerate() {
            let last_of_window = (WARM_UP + WINDOW - 1) as usize;
            let expected = if k < last_of_window { before } else { lowered };
            assert_eq!(n, expected, "item {k}");
        }
        // Never waits, or waits only in the warm-up, or for fewer than half: kept.
        for waited in [|_| false, |k| k < WARM_UP, |k| k % 2 == 0 && k != WARM_UP] {
            assert!(run(waited).into_iter().all(|n| n == before));
        }
        // Waits only after the window: the decision was made already.
        assert!(run(|k| k >= WARM_UP + WINDOW)
            .into_iter()
            .all(|n| n == before));
    }

    #[test]
    fn recv_hands_on_every_item_in_order_and_counts_the_ones_already_there() {
        let (tx, rx) = std::sync::mpsc::channel::<u32>();
        let mut c = Consumer::new("test");
        for k in 0..WARM_UP + 3 {
            tx.send(k).unwrap();
            assert_eq!(c.recv(&rx), Ok(k));
        }
        assert_eq!(
            (c.seen, c.waits),
            (WARM_UP + 3, 0),
            "none of these was waited for"
        );
        // An item that comes later is still handed on; the end of the producer ends it.
        let sender = std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_millis(20));
            tx.send(99).unwrap();
        });
        assert_eq!(c.recv(&rx), Ok(99));
        sender.join().unwrap();
        assert_eq!(c.recv(&rx), Err(RecvError));
    }

    #[test]
    fn only_the_calling_thread_and_what_it_spawns_are_lowered_never_raised() {
        let before = own_nice();
        let (lowered, child) = std::thread::spawn(|| {
            lower_this_thread();
            let child = std::thread::spawn(own_nice).join().unwrap();
            (own_nice(), child)
        })
        .join()
        .unwrap();
        // Lowered to the target, or left where it was when that is already as low or lower.
        assert_eq!(lowered, target().max(before));
        assert_eq!(
            child, lowered,
            "a thread spawned by a lowered one inherits it"
        );
        assert_eq!(
            own_nice(),
            before,
            "the calling thread of the test is untouched"
        );
        // A thread already below the target is never raised.
        let stays = std::thread::spawn(|| {
            set_nice(19);
            lower_this_thread();
            own_nice()
        })
        .join()
        .unwrap();
        assert_eq!(stays, 19);
    }
}

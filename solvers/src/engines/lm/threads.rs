//! The native LM on a thread pool of its own ([`LevenbergMarquardt::threads`]).

use crate::{Iteration, Observer, Solution};

/// Forwards each iteration of a solve running on another thread to the caller's observer.
struct Relay {
    tx: std::sync::mpsc::Sender<Iteration>,
    wants: bool,
}

impl Observer for Relay {
    fn iteration(&mut self, it: &Iteration) {
        // The receiver lives until the solve ends.
        let _ = self.tx.send(*it);
    }

    fn wants_metrics(&self) -> bool {
        self.wants
    }
}

/// `solve` run on a rayon pool of `threads` threads built for it, its iterations reported to
/// `observer` on the calling thread as they come; `None` when the pool cannot be built (the
/// system refuses the threads). A panic in the solve goes on in the caller.
pub(super) fn on_threads(
    threads: usize,
    observer: &mut dyn Observer,
    solve: impl FnOnce(&mut dyn Observer) -> Solution + Send,
) -> Option<Solution> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .ok()?;
    let wants = observer.wants_metrics();
    let (tx, rx) = std::sync::mpsc::channel::<Iteration>();
    let joined = std::thread::scope(|scope| {
        let solving = scope.spawn(move || {
            let mut relay = Relay { tx, wants };
            pool.install(|| solve(&mut relay))
        });
        for it in rx {
            observer.iteration(&it);
        }
        solving.join()
    });
    match joined {
        Ok(solution) => Some(solution),
        Err(panic) => std::panic::resume_unwind(panic),
    }
}

//! Ranks as threads of one process (`--ranks N`, and the tests' stand-in
//! for MPI): each bound to its share of the cores, meeting at every
//! collective, a rank that fails ending the others at their next one.

use super::*;

/// Ranks as threads of one process, for tests of what ranks exchange
/// without MPI: every collective meets at a barrier and copies what each
/// rank put in its slot. Traffic is counted as `comm::MpiComm`
/// counts it (the form-factor exchanges only).
pub struct ThreadComm {
    rank: usize,
    shared: Arc<Meeting>,
    traffic: Cell<Traffic>,
    next_pool: Cell<u64>,
}

/// Each rank thread's cores: the process's own cores cut into `ranks`
/// equal runs, as `mpirun --bind-to core` binds processes (a thread left to
/// wander between cores was 6-10 % slower; the scheduler moved it off its
/// caches). None where the ranks outnumber the cores or the mask cannot
/// be read.
fn rank_cores(ranks: usize) -> Vec<rustix::thread::CpuSet> {
    use rustix::thread::{sched_getaffinity, CpuSet};
    let Ok(mine) = sched_getaffinity(None) else {
        return Vec::new();
    };
    let cpus: Vec<usize> = (0..CpuSet::MAX_CPU).filter(|&c| mine.is_set(c)).collect();
    let each = cpus.len() / ranks.max(1);
    if each == 0 {
        return Vec::new();
    }
    cpus.chunks(each)
        .take(ranks)
        .map(|run| {
            let mut set = CpuSet::new();
            run.iter().for_each(|&c| set.set(c));
            set
        })
        .collect()
}

/// What each rank put down for the collective under way.
type Slots = Vec<Option<Box<dyn Any + Send + Sync>>>;

struct Meeting {
    size: usize,
    slots: RwLock<Slots>,
    /// Ranks arrived at the barrier under way and its generation.
    arrived: Mutex<(usize, u64)>,
    turned: Condvar,
    /// A rank failed (an error or a panic): the others leave at their
    /// next meeting instead of waiting for it forever.
    failed: AtomicBool,
    tickets: AtomicU64,
}

/// Unwinds a rank whose peer failed (see [`Meeting::failed`]); it carries
/// no message (the failed rank's is the one to tell).
struct PeerFailed;

impl Meeting {
    fn new(size: usize) -> Self {
        Self {
            size,
            slots: RwLock::new((0..size).map(|_| None).collect()),
            arrived: Mutex::new((0, 0)),
            turned: Condvar::new(),
            failed: AtomicBool::new(false),
            tickets: AtomicU64::new(0),
        }
    }

    /// Waits for every rank (a barrier), or unwinds where one failed.
    fn wait(&self) {
        let mut state = self.arrived.lock().unwrap_or_else(|p| p.into_inner());
        let generation = state.1;
        state.0 += 1;
        if state.0 == self.size {
            *state = (0, generation + 1);
            self.turned.notify_all();
            return;
        }
        while state.1 == generation {
            if self.failed.load(Ordering::Acquire) {
                drop(state);
                // `resume_unwind` runs no panic hook: nothing is printed.
                std::panic::resume_unwind(Box::new(PeerFailed));
            }
            state = self.turned.wait(state).unwrap_or_else(|p| p.into_inner());
        }
    }

    /// Marks a rank failed and wakes every waiting one.
    fn fail(&self) {
        self.failed.store(true, Ordering::Release);
        let _held = self.arrived.lock().unwrap_or_else(|p| p.into_inner());
        self.turned.notify_all();
    }
}

impl ThreadComm {
    /// Runs `f` on `ranks` threads, each with its rank's communicator, and
    /// returns their results in rank order. A panic on any rank panics here.
    pub fn run<T: Send>(ranks: usize, f: impl Fn(&ThreadComm) -> T + Sync) -> Vec<T> {
        let outcomes = Self::spawn(ranks, (None, 0), |_| false, f);
        // A rank's own panic first, not the others' unwinding after it.
        let mut ended = None;
        let mut results = Vec::with_capacity(outcomes.len());
        for out in outcomes {
            match out {
                Ok(t) => results.push(t),
                Err(p) if p.is::<PeerFailed>() => ended = Some(p),
                Err(p) => std::panic::resume_unwind(p),
            }
        }
        if let Some(p) = ended {
            std::panic::resume_unwind(p);
        }
        results
    }

    /// `f` on `ranks` threads, each with its communicator and, where
    /// `cores` is given, that many cores of its own (bound to them where
    /// the process has enough). A rank that panics, or whose result
    /// `failed` says failed, ends every other rank at its next collective
    /// call (they unwind with [`PeerFailed`]).
    fn spawn<T: Send>(
        ranks: usize,
        (cores, process): (Option<usize>, usize),
        failed: impl Fn(&T) -> bool + Sync,
        f: impl Fn(&ThreadComm) -> T + Sync,
    ) -> Vec<std::thread::Result<T>> {
        let shared = Arc::new(Meeting::new(ranks));
        let places = if cores.is_some() {
            rank_cores(ranks)
        } else {
            Vec::new()
        };
        std::thread::scope(|s| {
            let handles: Vec<_> = (0..ranks)
                .map(|rank| {
                    let (shared, f, failed, places) = (shared.clone(), &f, &failed, &places);
                    s.spawn(move || {
                        if let Some(set) = places.get(rank) {
                            // Only time depends on it: a rank left unbound still runs.
                            let _ = rustix::thread::sched_setaffinity(None, set);
                        }
                        if let Some(cores) = cores {
                            RANK_THREAD.set(Some(RankThread {
                                cores,
                                rank,
                                ranks,
                                process,
                            }));
                        }
                        let comm = ThreadComm {
                            rank,
                            shared: shared.clone(),
                            traffic: Cell::default(),
                            next_pool: Cell::default(),
                        };
                        let out =
                            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(&comm)));
                        if out.as_ref().is_ok_and(|t| !failed(t)) {
                            return out;
                        }
                        shared.fail();
                        out
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().unwrap_or_else(Err))
                .collect()
        })
    }

    /// Runs `f` as `ranks` ranks, each a thread of this process with its
    /// share of the cores ([`cores`] divided between them, at least one
    /// each, each bound to its own as `mpirun --bind-to core` binds
    /// processes): what `mpirun -n ranks` does, on one machine without
    /// MPI. Returns rank 0's result, or the first failure: a rank that
    /// returns an error or panics ends every other rank at its next
    /// collective call (a panic resumes here).
    pub fn ranks<T: Send, E: Send>(
        ranks: usize,
        f: impl Fn(&ThreadComm) -> Result<T, E> + Sync,
    ) -> Result<T, E> {
        let ranks = ranks.max(1);
        let process = cores();
        let each = (process / ranks).max(1);
        // The worker threads start now, sized for the whole process (a
        // rank thread would size them for its own share).
        scope(|_| {});
        let outcomes = Self::spawn(ranks, (Some(each), process), Result::is_err, f);
        // A real failure before the ranks it ended (which unwound quietly),
        // then rank 0's result.
        let mut outcomes = outcomes.into_iter();
        let zero = outcomes.next();
        let mut panicked = None;
        for out in outcomes {
            match out {
                Ok(Ok(_)) => {}
                Ok(Err(e)) => return Err(e),
                Err(p) if p.is::<PeerFailed>() => {}
                Err(p) => panicked = panicked.or(Some(p)),
            }
        }
        match zero {
            Some(Ok(result)) => match (result, panicked) {
                (Err(e), _) => Err(e),
                (Ok(_), Some(p)) => std::panic::resume_unwind(p),
                (Ok(t), None) => Ok(t),
            },
            Some(Err(p)) => std::panic::resume_unwind(panicked.unwrap_or(p)),
            None => std::panic::resume_unwind(panicked.unwrap_or_else(|| Box::new(PeerFailed))),
        }
    }

    /// See [`built_once`]: rank 0 builds (its share of the cores raised
    /// to the whole process's while the others wait idle), every rank
    /// takes a copy.
    pub(super) fn copy_of_rank_zeros<T: Clone + Send + Sync + 'static>(
        &self,
        build: impl FnOnce() -> T,
    ) -> T {
        let mine = (self.rank == 0).then(|| {
            let own = RANK_THREAD.get();
            if let Some(r) = own {
                RANK_THREAD.set(Some(RankThread {
                    cores: r.process,
                    ..r
                }));
            }
            let built = Arc::new(build());
            RANK_THREAD.set(own);
            built
        });
        let copy = self.meet_with(mine, |all| {
            all.first().and_then(|zero| zero.as_deref()).cloned()
        });
        // Rank 0 always puts its result down, and every rank makes this call.
        copy.unwrap_or_else(|| panic!("rank {} found nothing from rank 0", self.rank))
    }

    /// Every rank's `mine`, in rank order.
    fn meet<T: Clone + Send + Sync + 'static>(&self, mine: T) -> Vec<T> {
        self.meet_with(mine, |all| all.iter().map(|&t| t.clone()).collect())
    }

    /// `read` of every rank's `mine`, in rank order, while they lie there
    /// (so a rank copies only what it takes: an all-to-all's column).
    fn meet_with<T: Send + Sync + 'static, R>(&self, mine: T, read: impl FnOnce(&[&T]) -> R) -> R {
        self.shared.slots.write().unwrap_or_else(|p| p.into_inner())[self.rank] =
            Some(Box::new(mine));
        self.shared.wait();
        let out = {
            let slots = self.shared.slots.read().unwrap_or_else(|p| p.into_inner());
            let all: Vec<&T> = slots
                .iter()
                .map(|s| {
                    s.as_ref()
                        .and_then(|b| b.downcast_ref::<T>())
                        .expect("every rank makes the same collective calls")
                })
                .collect();
            read(&all)
        };
        // Nobody writes the next call's slot before everyone has read this one.
        self.shared.wait();
        out
    }

    fn count(&self, sent: usize, received: usize) {
        let t = self.traffic.get();
        self.traffic.set(Traffic {
            sent: t.sent + sent as u64,
            received: t.received + received as u64,
            calls: t.calls + 1,
            ..t
        });
    }
}

impl Collectives for ThreadComm {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.shared.size
    }
    fn all_gather_f64(&self, local: &[f64]) -> Vec<f64> {
        self.meet_with(local.to_vec(), |all| {
            all.iter().flat_map(|v| v.iter().copied()).collect()
        })
    }
    fn all_gather_u32(&self, local: &[u32], _lengths: Option<&[usize]>) -> Vec<Vec<u32>> {
        let all = self.meet(local.to_vec());
        let total: usize = all.iter().map(Vec::len).sum();
        self.count(
            4 * local.len() * (self.size() - 1),
            4 * (total - local.len()),
        );
        all
    }
    fn reduce_broadcast_sum(&self, data: &mut [u64]) {
        self.meet_with(data.to_vec(), |all| {
            for (i, d) in data.iter_mut().enumerate() {
                *d = all.iter().fold(0u64, |s, v| s.wrapping_add(v[i]));
            }
        });
        self.count(8 * data.len(), 8 * data.len());
    }
    fn all_to_all_pairs(&self, outgoing: &[Vec<(u32, u64)>]) -> Vec<(u32, u64)> {
        let me = self.rank;
        let incoming: Vec<(u32, u64)> = self.meet_with(outgoing.to_vec(), |all| {
            all.iter()
                .flat_map(|from| from[me].iter().copied())
                .collect()
        });
        let n = self.size();
        let own = outgoing[me].len();
        let out: usize = outgoing.iter().map(Vec::len).sum();
        self.count(
            12 * (out - own) + 4 * n,
            12 * (incoming.len() - own) + 4 * n,
        );
        incoming
    }
    fn all_to_all_u32(&self, outgoing: &[Vec<u32>]) -> Vec<Vec<u32>> {
        let me = self.rank;
        let incoming: Vec<Vec<u32>> = self.meet_with(outgoing.to_vec(), |all| {
            all.iter().map(|from| from[me].clone()).collect()
        });
        let words = |v: &[Vec<u32>]| v.iter().map(Vec::len).sum::<usize>();
        self.count(
            4 * (words(outgoing) - outgoing[me].len()),
            4 * (words(&incoming) - incoming[me].len()),
        );
        incoming
    }
    fn all_to_all_u32_into(&self, outgoing: &[Vec<u32>], incoming: &mut Vec<u32>) -> Vec<usize> {
        let me = self.rank;
        incoming.clear();
        let starts = self.meet_with(outgoing.to_vec(), |all| {
            let mut starts = Vec::with_capacity(all.len() + 1);
            starts.push(0);
            for from in all {
                incoming.extend_from_slice(&from[me]);
                starts.push(incoming.len());
            }
            starts
        });
        let words: usize = outgoing.iter().map(Vec::len).sum();
        self.count(
            4 * (words - outgoing[me].len()),
            4 * (incoming.len() - outgoing[me].len()),
        );
        starts
    }
    fn gather_f64(&self, local: &[f64]) -> Option<Vec<Vec<f64>>> {
        // Only rank 0 copies what it gathers.
        let root = self.rank == 0;
        self.meet_with(local.to_vec(), |all| {
            root.then(|| all.iter().map(|&v| v.clone()).collect())
        })
    }
    fn all_ok(&self, ok: Result<(), String>) -> Result<(), Vec<(usize, String)>> {
        let all = self.meet(ok.err());
        let failed: Vec<(usize, String)> = all
            .into_iter()
            .enumerate()
            .filter_map(|(r, m)| Some((r, m?)))
            .collect();
        match (failed.is_empty(), self.rank) {
            (true, _) => Ok(()),
            (false, 0) => Err(failed),
            (false, _) => Err(Vec::new()),
        }
    }
    fn take_ticket(&self) -> u64 {
        self.shared.tickets.fetch_add(1, Ordering::Relaxed)
    }
    fn open_pool(&self, len: usize) -> u64 {
        advance(&self.next_pool, len, self.size())
    }
    fn traffic(&self) -> Traffic {
        self.traffic.get()
    }
    fn abort(&self, code: i32) -> ! {
        panic!("rank {} aborted the run with code {code}", self.rank)
    }
    fn threads(&self) -> Option<&ThreadComm> {
        Some(self)
    }
}

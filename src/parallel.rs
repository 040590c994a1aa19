//! The collectives a distributed solve needs, as a trait, so the render loop
//! can run on one process or on MPI ranks without knowing which. The MPI
//! implementation lives in `comm`, the only module that calls MPI.

use std::any::Any;
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, RwLock};

mod threads;
pub use threads::ThreadComm;

/// Bytes this rank sent and received in exchanges, summed over calls, and
/// what the calls cost.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Traffic {
    /// Bytes sent.
    pub sent: u64,
    /// Bytes received.
    pub received: u64,
    /// Collective calls made.
    pub calls: u64,
    /// Process CPU seconds spent inside those calls, waiting included (MPI
    /// polls while it waits, so under oversubscription this is what a
    /// rank's CPU time must lose to count its own work).
    pub cpu_seconds: f64,
}

impl Traffic {
    /// What was added since `before`.
    pub fn since(self, before: Traffic) -> Traffic {
        Traffic {
            sent: self.sent.saturating_sub(before.sent),
            received: self.received.saturating_sub(before.received),
            calls: self.calls.saturating_sub(before.calls),
            cpu_seconds: (self.cpu_seconds - before.cpu_seconds).max(0.0),
        }
    }

    /// The sum of two tallies.
    pub fn plus(self, other: Traffic) -> Traffic {
        Traffic {
            sent: self.sent + other.sent,
            received: self.received + other.received,
            calls: self.calls + other.calls,
            cpu_seconds: self.cpu_seconds + other.cpu_seconds,
        }
    }
}

/// CPU seconds this rank has used so far: its process's (all its threads,
/// the GPU driver's included), or, for a rank that is a thread of a
/// process holding several ([`ThreadComm::ranks`]), its thread's.
pub fn process_cpu_seconds() -> f64 {
    let clock = if RANK_THREAD.get().is_some() {
        rustix::time::ClockId::ThreadCPUTime
    } else {
        rustix::time::ClockId::ProcessCPUTime
    };
    let t = rustix::time::clock_gettime(clock);
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

/// What a rank that is a thread of this process knows of itself
/// ([`ThreadComm::ranks`]): the cores it may use and its rank.
#[derive(Clone, Copy)]
struct RankThread {
    cores: usize,
    rank: usize,
    ranks: usize,
    /// The whole process's cores.
    process: usize,
}

thread_local! {
    static RANK_THREAD: Cell<Option<RankThread>> = const { Cell::new(None) };
}

/// The ranks this process holds: those of `--ranks` inside one of them
/// ([`ThreadComm::ranks`]), else 1. What a rank may take of the process's
/// resident memory is its share (see `render::source`'s row cache budget).
pub fn ranks_in_this_process() -> usize {
    RANK_THREAD.get().map_or(1, |r| r.ranks)
}

/// Whether this thread is a rank other than 0 of a process holding
/// several: such a rank logs warnings and errors only, as one under
/// mpirun does (the binary's logger asks).
pub fn quiet_rank() -> bool {
    RANK_THREAD.get().is_some_and(|r| r.rank > 0)
}

/// A span of this process's CPU time, less what collective calls used in it.
#[derive(Clone, Copy, Debug)]
pub struct CpuSpan {
    cpu: f64,
    mpi: f64,
}

impl CpuSpan {
    /// Starts a span.
    pub fn start(comm: &dyn Collectives) -> Self {
        Self {
            cpu: process_cpu_seconds(),
            mpi: comm.traffic().cpu_seconds,
        }
    }

    /// CPU seconds since the start outside collective calls.
    pub fn own(&self, comm: &dyn Collectives) -> f64 {
        let cpu = process_cpu_seconds() - self.cpu;
        let mpi = comm.traffic().cpu_seconds - self.mpi;
        (cpu - mpi).max(0.0)
    }
}

/// Collective operations over the ranks of one solve. Every rank must make
/// the same calls in the same order.
pub trait Collectives {
    /// This rank, 0-based.
    fn rank(&self) -> usize;
    /// Number of ranks.
    fn size(&self) -> usize;
    /// Every rank's `local` (the same length on every rank), concatenated in rank order.
    fn all_gather_f64(&self, local: &[f64]) -> Vec<f64>;
    /// Every rank's `local` (any length), in rank order. `lengths` gives every
    /// rank's length when all ranks already know them, which saves a collective.
    fn all_gather_u32(&self, local: &[u32], lengths: Option<&[usize]>) -> Vec<Vec<u32>>;
    /// Element-wise sum of `data` over ranks, reduced to rank 0 and broadcast back.
    fn reduce_broadcast_sum(&self, data: &mut [u64]);
    /// Sends `outgoing[r]` to rank r; returns everything sent to this rank, in rank order.
    fn all_to_all_pairs(&self, outgoing: &[Vec<(u32, u64)>]) -> Vec<(u32, u64)>;
    /// Sends `outgoing[r]` to rank r; returns what each rank sent to this
    /// one, in rank order (this rank's own included).
    fn all_to_all_u32(&self, outgoing: &[Vec<u32>]) -> Vec<Vec<u32>>;
    /// As [`Collectives::all_to_all_u32`], into `incoming` (its words
    /// replaced, its allocation kept, so a caller that keeps it between
    /// calls copies and faults in no fresh pages): what rank r sent is
    /// `incoming[starts[r]..starts[r + 1]]`, and `starts` (`size() + 1` of
    /// them) is returned.
    fn all_to_all_u32_into(&self, outgoing: &[Vec<u32>], incoming: &mut Vec<u32>) -> Vec<usize> {
        let parts = self.all_to_all_u32(outgoing);
        incoming.clear();
        let mut starts = Vec::with_capacity(parts.len() + 1);
        starts.push(0);
        for part in parts {
            incoming.extend_from_slice(&part);
            starts.push(incoming.len());
        }
        starts
    }
    /// Rank 0 gets every rank's `local`, in rank order; the others get `None`.
    fn gather_f64(&self, local: &[f64]) -> Option<Vec<Vec<f64>>>;
    /// Whether every rank passed `ok`; when not, rank 0 gets the failing
    /// ranks' messages (`(rank, message)`), the others an empty list.
    fn all_ok(&self, ok: Result<(), String>) -> Result<(), Vec<(usize, String)>>;
    /// The next ticket of a counter every rank shares (0, 1, 2, ... over
    /// the run, each ticket to exactly one caller). Not a collective: a rank
    /// takes one whenever it is free, without the others taking part (see
    /// [`pool`]).
    fn take_ticket(&self) -> u64;
    /// The first ticket of a pool of `len` items (see [`pool`]): every
    /// rank leaves a pool by taking exactly one ticket past its end, so
    /// the next pool starts `len + size()` tickets on, known to all without
    /// a word. Every rank opens the same pools in the same order.
    fn open_pool(&self, len: usize) -> u64;
    /// Bytes exchanged so far by the form-factor exchanges.
    fn traffic(&self) -> Traffic;
    /// Ends every rank now (after an error that only this rank saw).
    fn abort(&self, code: i32) -> !;
    /// The ranks as threads of this process, where they are (see
    /// [`built_once`]); `None` for processes, which share no memory.
    fn threads(&self) -> Option<&ThreadComm> {
        None
    }
}

/// `build()`, the same on every rank (a mesh), made once where the ranks
/// are threads of one process: rank 0 builds it with every core of the
/// process while the others wait, and each takes a copy. Ranks that are
/// processes (MPI) each build their own. Every rank calls it alike.
pub fn built_once<T: Clone + Send + Sync + 'static>(
    comm: &dyn Collectives,
    build: impl FnOnce() -> T,
) -> T {
    match comm.threads() {
        Some(t) if t.size() > 1 => t.copy_of_rank_zeros(build),
        _ => build(),
    }
}

/// One process: every collective is the identity, and nothing travels.
#[derive(Default)]
pub struct Single {
    tickets: Cell<u64>,
}

/// The first ticket of the next pool, advanced past a pool of `len` on
/// `ranks` ranks (every `Collectives`' `open_pool`; with `len` 0 and one
/// rank, a plain counter).
pub(crate) fn advance(next: &Cell<u64>, len: usize, ranks: usize) -> u64 {
    let first = next.get();
    next.set(first + (len + ranks) as u64);
    first
}

impl Collectives for Single {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn all_gather_f64(&self, local: &[f64]) -> Vec<f64> {
        local.to_vec()
    }
    fn all_gather_u32(&self, local: &[u32], _lengths: Option<&[usize]>) -> Vec<Vec<u32>> {
        vec![local.to_vec()]
    }
    fn reduce_broadcast_sum(&self, _data: &mut [u64]) {}
    fn all_to_all_pairs(&self, outgoing: &[Vec<(u32, u64)>]) -> Vec<(u32, u64)> {
        outgoing.first().cloned().unwrap_or_default()
    }
    fn all_to_all_u32(&self, outgoing: &[Vec<u32>]) -> Vec<Vec<u32>> {
        vec![outgoing.first().cloned().unwrap_or_default()]
    }
    fn gather_f64(&self, local: &[f64]) -> Option<Vec<Vec<f64>>> {
        Some(vec![local.to_vec()])
    }
    fn all_ok(&self, ok: Result<(), String>) -> Result<(), Vec<(usize, String)>> {
        ok.map_err(|m| vec![(0, m)])
    }
    fn take_ticket(&self) -> u64 {
        advance(&self.tickets, 0, 1)
    }
    fn open_pool(&self, _len: usize) -> u64 {
        // One rank takes a pool's items without tickets.
        self.tickets.get()
    }
    fn traffic(&self) -> Traffic {
        Traffic::default()
    }
    fn abort(&self, code: i32) -> ! {
        std::process::exit(code)
    }
}

/// The cores this process may use, asked once: `available_parallelism`
/// reads the affinity mask and the cgroup's quota files on every call
/// (about 20 us), and every shot of a small scene asked it several times.
/// Under mpirun the ranks on one host share its cores, as their lavapipe
/// devices do (`launch::share_cores_between_ranks`), so unbound ranks do
/// not each spawn a worker for every core of the host.
pub fn cores() -> usize {
    if let Some(n) = RANK_THREAD.get() {
        return n.cores;
    }
    static CORES: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *CORES.get_or_init(|| {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        (cores / ranks_on_this_host()).max(1)
    })
}

/// Runs `f` with this thread's share of the cores set to `n` (what
/// [`cores`] answers here, so its forks split `n` ways), then restores the
/// share it had. A thread that draws rows beside another
/// (`render::ahead`) takes one core, as a rank of `--ranks` takes its own.
pub fn with_cores<R>(n: usize, f: impl FnOnce() -> R) -> R {
    let own = RANK_THREAD.get();
    let process = own.map_or_else(cores, |r| r.process);
    RANK_THREAD.set(Some(match own {
        Some(r) => RankThread {
            cores: n.max(1),
            ..r
        },
        None => RankThread {
            cores: n.max(1),
            rank: 0,
            ranks: 1,
            process,
        },
    }));
    // Restored on unwinding too: the thread may go on after a caught panic.
    struct Restore(Option<RankThread>);
    impl Drop for Restore {
        fn drop(&mut self) {
            RANK_THREAD.set(self.0);
        }
    }
    let _restore = Restore(own);
    f()
}

/// Runs `op` on this thread with a scope whose spawned work runs on the
/// process's worker threads ([`cores`] less one of them, started at the
/// first call; this thread is the other), as `std::thread::scope` does
/// without starting a thread each time: a shot forks and joins several
/// times, and starting and joining a thread took about 25 us here, a
/// sixth of a Cornell box's shot. Spawned work must not wait on other
/// spawned work (each call here only forks and joins).
pub fn scope<'scope, R>(op: impl FnOnce(&rayon_core::Scope<'scope>) -> R) -> R {
    static WORKERS: std::sync::Once = std::sync::Once::new();
    WORKERS.call_once(|| {
        // If it fails (threads cannot start), rayon's own global pool is
        // built at the first spawn instead: the same work, more threads.
        let built = rayon_core::ThreadPoolBuilder::new()
            .num_threads(cores().saturating_sub(1).max(1))
            .thread_name(|k| format!("radiosity worker {k}"))
            .build_global();
        if let Err(e) = built {
            log::debug!("worker threads: {e}");
        }
    });
    rayon_core::in_place_scope(op)
}

/// `work(k, part)` for every part, the first on this thread and the rest
/// on the worker threads ([`scope`]); the results in part order (a
/// worker's panic resumes here).
pub fn each<P: Send, T: Send>(
    parts: impl ExactSizeIterator<Item = P>,
    work: impl Fn(usize, P) -> T + Sync,
) -> Vec<T> {
    let mut out: Vec<Option<T>> = (0..parts.len()).map(|_| None).collect();
    scope(|s| {
        let work = &work;
        let mut jobs = parts.zip(out.iter_mut()).enumerate();
        let first = jobs.next();
        for (k, (part, slot)) in jobs {
            s.spawn(move |_| *slot = Some(work(k, part)));
        }
        if let Some((k, (part, slot))) = first {
            *slot = Some(work(k, part));
        }
    });
    out.into_iter().flatten().collect()
}

/// The ranks mpirun started on this host (Open MPI's
/// `OMPI_COMM_WORLD_LOCAL_SIZE`; 1 outside mpirun).
pub fn ranks_on_this_host() -> usize {
    std::env::var("OMPI_COMM_WORLD_LOCAL_SIZE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1)
        .max(1)
}

/// Which rank draws each of a batch's rows, from `costs` (every rank's
/// cost of every row, rank by rank, as the render's source weighs them:
/// `GpuFormFactors::row_cost`): the costliest rows first, each to the rank where the sum of its
/// load and the row's cost there is least (the lower rank on ties). The
/// same answer on every rank.
pub fn assign_rows(costs: &[f64], ranks: usize) -> Vec<usize> {
    let k = costs.len() / ranks.max(1);
    let cost = |rank: usize, row: usize| costs[rank * k + row];
    // A row's cost where it is cheapest orders the rows.
    let least = |row: usize| {
        (0..ranks)
            .map(|r| cost(r, row))
            .fold(f64::INFINITY, f64::min)
    };
    let mut order: Vec<usize> = (0..k).collect();
    order.sort_by(|&a, &b| least(b).total_cmp(&least(a)).then(a.cmp(&b)));
    let mut load = vec![0.0; ranks];
    let mut drawer = vec![0; k];
    for row in order {
        let best = (0..ranks)
            .min_by(|&a, &b| {
                (load[a] + cost(a, row))
                    .total_cmp(&(load[b] + cost(b, row)))
                    .then(a.cmp(&b))
            })
            .unwrap_or(0);
        load[best] += cost(best, row);
        drawer[row] = best;
    }
    drawer
}

/// A pool of `len` items for this rank to take from, as it comes free:
/// every rank opens the same pools in the same order, each between two
/// collectives, and iterates its [`Claims`] to the end.
pub fn pool(comm: &dyn Collectives, len: usize) -> Claims<'_> {
    let first = if comm.size() > 1 && len > 0 {
        comm.open_pool(len)
    } else {
        0
    };
    Claims {
        comm,
        first,
        len,
        taken: 0,
    }
}

/// The items of one pool this rank takes, in the order it takes them.
pub struct Claims<'c> {
    comm: &'c dyn Collectives,
    first: u64,
    len: usize,
    taken: usize,
}

impl Iterator for Claims<'_> {
    type Item = usize;

    fn next(&mut self) -> Option<usize> {
        if self.len == 0 {
            return None;
        }
        if self.comm.size() == 1 {
            // One rank takes every item, in order, without tickets.
            let i = self.taken;
            self.taken += 1;
            return (i < self.len).then_some(i);
        }
        if self.taken > self.len {
            return None;
        }
        let ticket = self.comm.take_ticket();
        let i = ticket.wrapping_sub(self.first) as usize;
        debug_assert!(ticket >= self.first, "ranks opened different pools");
        if i < self.len {
            Some(i)
        } else {
            // This rank's one ticket past the end: it leaves the pool.
            self.taken = self.len + 1;
            None
        }
    }
}

/// Patches a rank owns in a row, at least and at most (see [`Owners`]).
pub const OWNED_RUN: [usize; 2] = [8, 256];

/// Runs each rank gets at least, where the patches allow runs longer than
/// the shortest: enough that the runs even out what lands where.
const RUNS_PER_RANK: usize = 64;

/// Which rank owns which patch (an element belongs to its patch's owner):
/// runs of patches dealt in turn. The runs are as long as the patches
/// allow up to [`OWNED_RUN`]'s most, with [`RUNS_PER_RANK`] runs a rank or
/// more: a rank's elements then fill whole pages of the solver's arrays,
/// which a shot's landing reaches at random (in a big scene each element
/// it touched was a TLB miss, so two ranks each landing half the transfers
/// took 0.64 of one rank's time; with runs of 256, 0.51). The one place
/// this rule lives. Deterministic in the patch and rank counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Owners {
    run: usize,
    ranks: usize,
}

impl Owners {
    /// The owners of `patches` patches over `ranks` ranks.
    pub fn new(patches: usize, ranks: usize) -> Self {
        let ranks = ranks.max(1);
        let [least, most] = OWNED_RUN;
        let mut run = most;
        while run > least && patches < ranks * run * RUNS_PER_RANK {
            run /= 2;
        }
        Self { run, ranks }
    }

    /// Patches a rank owns in a row.
    pub fn run(&self) -> usize {
        self.run
    }

    /// The rank that owns patch `patch`.
    pub fn of(&self, patch: u32) -> usize {
        (patch as usize / self.run) % self.ranks
    }

    /// The patches rank `rank` owns, in increasing order, out of `patches`.
    pub fn patches(&self, rank: usize, patches: usize) -> impl Iterator<Item = usize> {
        let run = self.run;
        (rank * run..patches)
            .step_by(self.ranks * run)
            .flat_map(move |s| s..(s + run).min(patches))
    }

    /// How many of `patches` patches rank `rank` owns.
    pub fn count(&self, rank: usize, patches: usize) -> usize {
        let period = self.ranks * self.run;
        let full = patches / period * self.run;
        let rest = (patches % period)
            .saturating_sub(rank * self.run)
            .min(self.run);
        full + rest
    }

    /// The `k`-th patch (from 0) rank `rank` owns.
    pub fn at(&self, rank: usize, k: usize) -> usize {
        (k / self.run * self.ranks + rank) * self.run + k % self.run
    }

    /// Where patch `patch` comes among its owner's patches ([`Owners::at`]'s inverse).
    pub fn index(&self, patch: usize) -> usize {
        patch / (self.ranks * self.run) * self.run + patch % self.run
    }
}

/// How the ranks exchange form factors each shot (DESIGN.md section 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Exchange {
    /// All-gather the partial item buffers; every rank sums F itself (the paper's new method).
    #[default]
    Hemispheres,
    /// Dense partial form factors over all elements, reduced and broadcast (the paper's earlier method).
    FormFactors,
    /// Nonzero (element, F) pairs sent straight to the owning ranks.
    Sparse,
}

/// The Px x Py rank grid for `n` ranks: Py is the largest divisor of n not
/// above sqrt(n), so the grid is as square as n allows (a prime n gives n x 1).
pub fn rank_grid(n: usize) -> (u32, u32) {
    let n = n.max(1);
    let py = (1..=n)
        .take_while(|d| d * d <= n)
        .filter(|d| n % d == 0)
        .max()
        .unwrap_or(1);
    ((n / py) as u32, py as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranks_in_threads_meet_and_give_rank_zeros_result() {
        let got = ThreadComm::ranks(3, |c| {
            // Each rank has its share of the cores, at least one.
            assert_eq!(
                cores(),
                (std::thread::available_parallelism().map_or(1, |n| n.get()) / 3).max(1)
            );
            assert_eq!(ranks_in_this_process(), 3);
            let all = c.all_gather_f64(&[c.rank() as f64]);
            let back =
                c.all_to_all_u32(&[vec![c.rank() as u32], vec![10 + c.rank() as u32], vec![]]);
            Ok::<_, String>((all, back))
        });
        let (all, back) = got.expect("no rank fails");
        assert_eq!(all, vec![0.0, 1.0, 2.0]);
        assert_eq!(back, vec![vec![0], vec![1], vec![2]]);
        // Outside a rank thread the process's cores again.
        assert!(RANK_THREAD.get().is_none());
        assert_eq!(ranks_in_this_process(), 1);
    }

    #[test]
    fn what_ranks_in_threads_build_once_is_built_once_with_every_core() {
        let builds = AtomicU64::new(0);
        let got = ThreadComm::ranks(3, |c| {
            let value = built_once(c, || {
                builds.fetch_add(1, Ordering::Relaxed);
                // Rank 0 builds with the process's cores, not its share.
                (c.rank(), cores())
            });
            Ok::<_, ()>((value, cores()))
        });
        let ((builder, cores_building), cores_after) = got.expect("no rank fails");
        assert_eq!(builds.load(Ordering::Relaxed), 1);
        assert_eq!(builder, 0);
        assert_eq!(cores_building, cores());
        assert_eq!(cores_after, (cores() / 3).max(1));
        // One process alone builds it itself.
        assert_eq!(built_once(&Single::default(), || 7), 7);
    }

    #[test]
    fn a_rank_that_fails_ends_the_others_with_its_error() {
        // Rank 1 fails before a collective the others wait in: they must
        // not wait for ever, and its error is the one returned.
        let got: Result<(), String> = ThreadComm::ranks(3, |c| {
            if c.rank() == 1 {
                return Err("rank 1 failed".into());
            }
            c.all_gather_f64(&[1.0]);
            Ok(())
        });
        assert_eq!(got, Err("rank 1 failed".to_string()));
        // A panic is resumed as itself, not as the others' unwinding.
        let panicked = std::panic::catch_unwind(|| {
            ThreadComm::ranks(2, |c| {
                if c.rank() == 0 {
                    panic!("rank 0 broke");
                }
                c.all_gather_f64(&[1.0]);
                Ok::<_, ()>(())
            })
        });
        let message = panicked.expect_err("the panic comes back");
        assert_eq!(message.downcast_ref::<&str>(), Some(&"rank 0 broke"));
    }

    #[test]
    fn rows_go_where_they_cost_least_and_balance() {
        // Two ranks, four rows: row 1 is cached on rank 1, row 3 coarse.
        let costs = [
            1.0, 1.0, 1.0, 0.25, // rank 0
            1.0, 0.02, 1.0, 0.25, // rank 1
        ];
        let drawer = assign_rows(&costs, 2);
        assert_eq!(drawer[1], 1, "the cached row on its cache's rank");
        let load = |r: usize| -> f64 {
            (0..4)
                .filter(|&k| drawer[k] == r)
                .map(|k| costs[r * 4 + k])
                .sum()
        };
        assert!((load(0) - load(1)).abs() <= 1.0, "{drawer:?}");
        // One rank draws everything.
        assert_eq!(assign_rows(&[1.0, 0.5], 1), vec![0, 0]);
    }

    #[test]
    fn every_pooled_item_is_taken_by_exactly_one_rank() {
        // Three ranks open pools of 7, 0, 1 and 40 items, a collective
        // between each (as a batch's exchanges are), and take as they come.
        let lens = [7usize, 0, 1, 40];
        let taken = ThreadComm::run(3, |c| {
            let mut mine = Vec::new();
            for &len in &lens {
                let got: Vec<usize> = pool(c, len).collect();
                mine.push(got);
                c.all_gather_f64(&[0.0]);
            }
            mine
        });
        for (p, &len) in lens.iter().enumerate() {
            let mut all: Vec<usize> = taken.iter().flat_map(|r| r[p].clone()).collect();
            all.sort_unstable();
            assert_eq!(all, (0..len).collect::<Vec<_>>(), "pool {p}");
        }
        // One rank takes every item in order.
        assert_eq!(
            pool(&Single::default(), 3).collect::<Vec<_>>(),
            vec![0, 1, 2]
        );
    }

    #[test]
    fn rank_grids() {
        assert_eq!(rank_grid(1), (1, 1));
        assert_eq!(rank_grid(4), (2, 2));
        assert_eq!(rank_grid(6), (3, 2));
        assert_eq!(rank_grid(7), (7, 1));
        assert_eq!(rank_grid(64), (8, 8));
        assert_eq!(rank_grid(8), (4, 2));
    }

    #[test]
    fn thread_ranks_meet_in_every_collective() {
        let out = ThreadComm::run(3, |c| {
            let r = c.rank() as u32;
            let gathered = c.all_gather_f64(&[r as f64]);
            let lists = c.all_gather_u32(&vec![r; c.rank()], None);
            let mut sum = [1u64, r as u64];
            c.reduce_broadcast_sum(&mut sum);
            let outgoing: Vec<Vec<(u32, u64)>> = (0..3).map(|to| vec![(r, to as u64)]).collect();
            let incoming = c.all_to_all_pairs(&outgoing);
            let ok = c.all_ok(if r == 2 { Err("two".into()) } else { Ok(()) });
            (
                gathered,
                lists,
                sum,
                incoming,
                ok,
                c.gather_f64(&[r as f64]).is_some(),
            )
        });
        for (rank, (g, l, s, inc, ok, root)) in out.into_iter().enumerate() {
            assert_eq!(g, vec![0.0, 1.0, 2.0]);
            assert_eq!(l, vec![vec![], vec![1], vec![2, 2]]);
            assert_eq!(s, [3, 3]);
            assert_eq!(
                inc,
                (0..3).map(|from| (from, rank as u64)).collect::<Vec<_>>()
            );
            match rank {
                0 => assert_eq!(ok, Err(vec![(2, "two".to_string())])),
                _ => assert_eq!(ok, Err(vec![])),
            }
            assert_eq!(root, rank == 0);
        }
    }

    #[test]
    fn patch_ownership_is_runs_dealt_in_turn() {
        let small = Owners::new(100, 3);
        assert_eq!(small.run(), OWNED_RUN[0]);
        let run = small.run() as u32;
        assert_eq!(small.of(0), 0);
        assert_eq!(small.of(run), 1);
        assert_eq!(small.of(3 * run + 1), 0);
        assert_eq!(Owners::new(100, 1).of(7), 0);
        // Runs grow with the patches, as long as each rank keeps its runs.
        assert_eq!(Owners::new(2 * 256 * RUNS_PER_RANK, 2).run(), OWNED_RUN[1]);
        assert_eq!(Owners::new(2 * 256 * RUNS_PER_RANK - 1, 2).run(), 128);
        assert_eq!(Owners::new(usize::MAX / 1024, 4096).run(), OWNED_RUN[1]);
        for ranks in 1..6 {
            for patches in [0, 1, 7, 20, 100, 257, 40_000, 70_001] {
                let owners = Owners::new(patches, ranks);
                let mut all = Vec::new();
                for r in 0..ranks {
                    let own: Vec<usize> = owners.patches(r, patches).collect();
                    assert_eq!(
                        own.len(),
                        owners.count(r, patches),
                        "{r}/{ranks} of {patches}"
                    );
                    for (k, &p) in own.iter().enumerate() {
                        assert_eq!(owners.of(p as u32), r);
                        assert_eq!(owners.at(r, k), p);
                        assert_eq!(owners.index(p), k);
                    }
                    assert!(own.windows(2).all(|w| w[0] < w[1]), "in increasing order");
                    all.extend(own);
                }
                all.sort_unstable();
                assert_eq!(all, (0..patches).collect::<Vec<_>>(), "every patch once");
            }
        }
    }
}

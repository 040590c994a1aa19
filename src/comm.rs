//! MPI plumbing (rsmpi): the [`Collectives`] of a solve spread over ranks.
//! This is the only module that calls MPI.

use crate::parallel::{process_cpu_seconds, Collectives, Traffic};
use mpi::datatype::{Partition, PartitionMut};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use mpi::Count;
use std::cell::Cell;

/// The tag of `all_to_all_u32_into`'s point-to-point messages (the only
/// tagged messages between ranks; each pair's arrive in order).
const ALL_TO_ALL_TAG: mpi::Tag = 19;

/// The MPI world of this process (a singleton world when not under mpirun).
pub struct MpiComm {
    // Dropping the universe finalises MPI, so it lives as long as the communicator.
    _universe: mpi::environment::Universe,
    world: SimpleCommunicator,
    traffic: Cell<Traffic>,
    /// The shared ticket counter (on more than one rank).
    tickets: Option<TicketWindow>,
    /// The ticket counter of a world of one rank.
    local_tickets: Cell<u64>,
    /// The first ticket of the next pool (see `Collectives::open_pool`).
    next_pool: Cell<u64>,
}

/// One u64 on rank 0 that every rank adds to atomically (MPI-3 one-sided:
/// `MPI_Fetch_and_op` under a passive `MPI_Win_lock_all` epoch held for the
/// whole run), so a rank takes a ticket without rank 0 taking part.
struct TicketWindow {
    win: mpi::ffi::MPI_Win,
}

impl TicketWindow {
    /// Collective over `world`: rank 0 holds the counter, at 0.
    fn new(world: &SimpleCommunicator) -> Option<Self> {
        use mpi::raw::AsRaw;
        let bytes = if world.rank() == 0 { 8 } else { 0 };
        let mut base: *mut u64 = std::ptr::null_mut();
        let mut win = std::mem::MaybeUninit::<mpi::ffi::MPI_Win>::uninit();
        // SAFETY: MPI allocates `bytes` bytes (aligned for any type) and
        // writes their address into `base` and the window's handle into `win`.
        let rc = unsafe {
            mpi::ffi::MPI_Win_allocate(
                bytes,
                8,
                mpi::ffi::RSMPI_INFO_NULL,
                world.as_raw(),
                (&mut base as *mut *mut u64).cast(),
                win.as_mut_ptr(),
            )
        };
        if rc != 0 {
            return None;
        }
        // SAFETY: MPI_Win_allocate succeeded, so `win` is initialised.
        let win = unsafe { win.assume_init() };
        if world.rank() == 0 && !base.is_null() {
            // SAFETY: rank 0's window is 8 bytes at `base`, which no rank
            // reaches before the barrier below.
            unsafe { base.write(0) };
        }
        world.barrier();
        // SAFETY: `win` is a valid window; the epoch ends in `Drop`.
        unsafe { mpi::ffi::MPI_Win_lock_all(0, win) };
        Some(Self { win })
    }

    /// The counter's value before this call's add of 1.
    fn take(&self) -> u64 {
        let one: u64 = 1;
        let mut before: u64 = 0;
        // SAFETY: both buffers are one u64, the type given; the target is
        // rank 0's displacement 0, inside its 8-byte window; the flush
        // completes the operation before `before` is read.
        unsafe {
            mpi::ffi::MPI_Fetch_and_op(
                (&one as *const u64).cast(),
                (&mut before as *mut u64).cast(),
                mpi::ffi::RSMPI_UINT64_T,
                0,
                0,
                mpi::ffi::RSMPI_SUM,
                self.win,
            );
            mpi::ffi::MPI_Win_flush(0, self.win);
        }
        before
    }
}

impl Drop for MpiComm {
    // The window is freed (collectively) before the universe finalises MPI.
    fn drop(&mut self) {
        if let Some(t) = self.tickets.take() {
            let mut win = t.win;
            // SAFETY: the epoch opened in `TicketWindow::new` is closed and
            // the window freed once, by every rank (as MPI_Finalize is).
            unsafe {
                mpi::ffi::MPI_Win_unlock_all(win);
                mpi::ffi::MPI_Win_free(&mut win);
            }
        }
    }
}

impl MpiComm {
    /// Initialises MPI; `None` if it was already initialised or cannot start
    /// (or, on more than one rank, cannot open the ticket window).
    pub fn init() -> Option<Self> {
        let universe = mpi::initialize()?;
        let world = universe.world();
        // A world of ranks without a shared counter cannot share work: no world.
        let tickets = if world.size() > 1 {
            Some(TicketWindow::new(&world)?)
        } else {
            None
        };
        Some(Self {
            _universe: universe,
            world,
            traffic: Cell::new(Traffic::default()),
            tickets,
            local_tickets: Cell::new(0),
            next_pool: Cell::new(0),
        })
    }

    /// Counts one collective call and, when the guard drops, the process CPU
    /// time it took (MPI polls while it waits).
    fn call(&self) -> CallTimer<'_> {
        CallTimer {
            traffic: &self.traffic,
            start: process_cpu_seconds(),
        }
    }

    fn count(&self, sent: usize, received: usize) {
        let mut t = self.traffic.get();
        t.sent += sent as u64;
        t.received += received as u64;
        self.traffic.set(t);
    }

    /// The layout of an all-to-all whose message to rank r has `lengths`'
    /// r-th length: the counts are exchanged first (one collective).
    fn plan(&self, lengths: impl Iterator<Item = usize>) -> AllToAll {
        let send_counts: Vec<Count> = lengths.map(|n| n as Count).collect();
        let mut recv_counts = vec![0 as Count; self.size()];
        self.world
            .all_to_all_into(&send_counts[..], &mut recv_counts[..]);
        AllToAll {
            send_displs: Self::displacements(&send_counts),
            recv_displs: Self::displacements(&recv_counts),
            send_counts,
            recv_counts,
        }
    }

    fn displacements(counts: &[Count]) -> Vec<Count> {
        counts
            .iter()
            .scan(0, |acc, &c| {
                let d = *acc;
                *acc += c;
                Some(d)
            })
            .collect()
    }

    fn all_counts(&self, len: usize) -> Vec<Count> {
        let mut counts = vec![0 as Count; self.size()];
        self.world.all_gather_into(&(len as Count), &mut counts[..]);
        counts
    }
}

/// Adds a call's CPU time to the tally when dropped.
struct CallTimer<'a> {
    traffic: &'a Cell<Traffic>,
    start: f64,
}

impl Drop for CallTimer<'_> {
    fn drop(&mut self) {
        let mut t = self.traffic.get();
        t.calls += 1;
        t.cpu_seconds += (process_cpu_seconds() - self.start).max(0.0);
        self.traffic.set(t);
    }
}

/// The counts and displacements of one all-to-all (see [`MpiComm::plan`]).
struct AllToAll {
    send_counts: Vec<Count>,
    send_displs: Vec<Count>,
    recv_counts: Vec<Count>,
    recv_displs: Vec<Count>,
}

impl AllToAll {
    /// Moves `data` (laid out by the send counts) to its ranks; returns
    /// what came, laid out by the receive counts.
    fn move_all<T: Equivalence + Copy + Default>(
        &self,
        world: &SimpleCommunicator,
        data: &[T],
    ) -> Vec<T> {
        let total: usize = self.recv_counts.iter().map(|&c| c as usize).sum();
        let mut incoming = vec![T::default(); total];
        let send = Partition::new(data, &self.send_counts[..], &self.send_displs[..]);
        let mut recv = PartitionMut::new(
            &mut incoming[..],
            &self.recv_counts[..],
            &self.recv_displs[..],
        );
        world.all_to_all_varcount_into(&send, &mut recv);
        incoming
    }

    fn ranks(&self) -> usize {
        self.send_counts.len()
    }

    /// Items this rank sent to the other ranks.
    fn sent_to_others(&self, me: usize) -> usize {
        let all: usize = self.send_counts.iter().map(|&c| c as usize).sum();
        all - self.send_counts[me] as usize
    }

    /// Items this rank received from the other ranks.
    fn received_from_others(&self, me: usize) -> usize {
        let all: usize = self.recv_counts.iter().map(|&c| c as usize).sum();
        all - self.recv_counts[me] as usize
    }
}

impl Collectives for MpiComm {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }

    fn size(&self) -> usize {
        self.world.size() as usize
    }

    fn all_gather_f64(&self, local: &[f64]) -> Vec<f64> {
        let _call = self.call();
        let mut out = vec![0.0; local.len() * self.size()];
        self.world.all_gather_into(local, &mut out[..]);
        out
    }

    fn all_gather_u32(&self, local: &[u32], lengths: Option<&[usize]>) -> Vec<Vec<u32>> {
        let _call = self.call();
        let counts = match lengths {
            Some(l) => l.iter().map(|&n| n as Count).collect(),
            None => self.all_counts(local.len()),
        };
        let displs = Self::displacements(&counts);
        let total: usize = counts.iter().map(|&c| c as usize).sum();
        let mut buf = vec![0u32; total];
        {
            let mut part = PartitionMut::new(&mut buf[..], &counts[..], &displs[..]);
            self.world.all_gather_varcount_into(local, &mut part);
        }
        self.count(
            4 * local.len() * (self.size() - 1),
            4 * (total - local.len()),
        );
        counts
            .iter()
            .zip(&displs)
            .map(|(&c, &d)| buf[d as usize..(d + c) as usize].to_vec())
            .collect()
    }

    fn reduce_broadcast_sum(&self, data: &mut [u64]) {
        let _call = self.call();
        let root = self.world.process_at_rank(0);
        if self.rank() == 0 {
            let mut sum = vec![0u64; data.len()];
            root.reduce_into_root(
                &data[..],
                &mut sum[..],
                mpi::collective::SystemOperation::sum(),
            );
            data.copy_from_slice(&sum);
        } else {
            root.reduce_into(&data[..], mpi::collective::SystemOperation::sum());
        }
        root.broadcast_into(&mut data[..]);
        // One reduction stage and one broadcast stage of the whole array per rank.
        self.count(8 * data.len(), 8 * data.len());
    }

    fn all_to_all_u32(&self, outgoing: &[Vec<u32>]) -> Vec<Vec<u32>> {
        let mut words = Vec::new();
        let starts = self.all_to_all_u32_into(outgoing, &mut words);
        starts
            .windows(2)
            .map(|w| words[w[0]..w[1]].to_vec())
            .collect()
    }

    fn all_to_all_u32_into(&self, outgoing: &[Vec<u32>], incoming: &mut Vec<u32>) -> Vec<usize> {
        let _call = self.call();
        let plan = self.plan(outgoing.iter().map(Vec::len));
        let me = self.rank();
        let starts: Vec<usize> = plan
            .recv_displs
            .iter()
            .map(|&d| d as usize)
            .chain(std::iter::once(
                plan.recv_counts.iter().map(|&c| c as usize).sum(),
            ))
            .collect();
        incoming.clear();
        incoming.resize(starts[starts.len() - 1], 0);
        // Point to point from each rank's own words into its place here:
        // an all-to-all of varying counts wants one send buffer, and
        // copying a batch's megabytes into one first cost more than the
        // transfer (pages the kernel zeroes, then the copy).
        let mut slices: Vec<&mut [u32]> = Vec::with_capacity(self.size());
        let mut rest = &mut incoming[..];
        for w in starts.windows(2) {
            let (here, after) = rest.split_at_mut(w[1] - w[0]);
            slices.push(here);
            rest = after;
        }
        mpi::request::scope(|scope| {
            let mut receives = Vec::new();
            let mut sends = Vec::new();
            for (r, slice) in slices.into_iter().enumerate() {
                if r == me {
                    slice.copy_from_slice(&outgoing[me]);
                } else if !slice.is_empty() {
                    let from = self.world.process_at_rank(r as mpi::Rank);
                    receives.push(from.immediate_receive_into_with_tag(
                        scope,
                        slice,
                        ALL_TO_ALL_TAG,
                    ));
                }
            }
            for (r, words) in outgoing.iter().enumerate() {
                if r != me && !words.is_empty() {
                    let to = self.world.process_at_rank(r as mpi::Rank);
                    sends.push(to.immediate_send_with_tag(scope, &words[..], ALL_TO_ALL_TAG));
                }
            }
            for r in receives {
                r.wait();
            }
            for s in sends {
                s.wait();
            }
        });
        self.count(
            4 * plan.sent_to_others(me) + 4 * plan.ranks(),
            4 * plan.received_from_others(me) + 4 * plan.ranks(),
        );
        starts
    }

    fn all_to_all_pairs(&self, outgoing: &[Vec<(u32, u64)>]) -> Vec<(u32, u64)> {
        let _call = self.call();
        let plan = self.plan(outgoing.iter().map(Vec::len));
        // Pairs travel as two flat arrays (element ids, fixed-point values).
        let ids: Vec<u32> = outgoing
            .iter()
            .flat_map(|v| v.iter().map(|p| p.0))
            .collect();
        let vals: Vec<u64> = outgoing
            .iter()
            .flat_map(|v| v.iter().map(|p| p.1))
            .collect();
        let in_ids = plan.move_all(&self.world, &ids);
        let in_vals = plan.move_all(&self.world, &vals);
        self.count(
            12 * plan.sent_to_others(self.rank()) + 4 * plan.ranks(),
            12 * plan.received_from_others(self.rank()) + 4 * plan.ranks(),
        );
        in_ids.into_iter().zip(in_vals).collect()
    }

    fn gather_f64(&self, local: &[f64]) -> Option<Vec<Vec<f64>>> {
        let _call = self.call();
        let root = self.world.process_at_rank(0);
        let mut counts = vec![0 as Count; self.size()];
        self.world
            .all_gather_into(&(local.len() as Count), &mut counts[..]);
        if self.rank() == 0 {
            let displs = Self::displacements(&counts);
            let total: usize = counts.iter().map(|&c| c as usize).sum();
            let mut buf = vec![0.0f64; total];
            {
                let mut part = PartitionMut::new(&mut buf[..], &counts[..], &displs[..]);
                root.gather_varcount_into_root(local, &mut part);
            }
            Some(
                counts
                    .iter()
                    .zip(&displs)
                    .map(|(&c, &d)| buf[d as usize..(d + c) as usize].to_vec())
                    .collect(),
            )
        } else {
            root.gather_varcount_into(local);
            None
        }
    }

    fn all_ok(&self, ok: Result<(), String>) -> Result<(), Vec<(usize, String)>> {
        let msg: Vec<u32> = match &ok {
            Ok(()) => Vec::new(),
            Err(m) => m.bytes().map(u32::from).chain(std::iter::once(0)).collect(),
        };
        // Message bytes travel as u32 so the exchange reuses the varcount gather.
        let all = self.all_gather_u32(&msg, None);
        let failed: Vec<(usize, String)> = all
            .iter()
            .enumerate()
            .filter(|(_, m)| !m.is_empty())
            .map(|(r, m)| {
                (
                    r,
                    String::from_utf8_lossy(
                        &m.iter()
                            .take_while(|&&b| b != 0)
                            .map(|&b| b as u8)
                            .collect::<Vec<u8>>(),
                    )
                    .into_owned(),
                )
            })
            .collect();
        // The check is not form-factor traffic.
        let t = self.traffic.get();
        self.traffic.set(Traffic {
            sent: t.sent - 4 * msg.len() as u64 * (self.size() as u64 - 1),
            received: t.received - 4 * (all.iter().map(Vec::len).sum::<usize>() - msg.len()) as u64,
            ..t
        });
        if failed.is_empty() {
            Ok(())
        } else if self.rank() == 0 {
            Err(failed)
        } else {
            Err(Vec::new())
        }
    }

    fn take_ticket(&self) -> u64 {
        match &self.tickets {
            Some(t) => {
                let _call = self.call();
                t.take()
            }
            None => crate::parallel::advance(&self.local_tickets, 0, 1),
        }
    }

    fn open_pool(&self, len: usize) -> u64 {
        crate::parallel::advance(&self.next_pool, len, self.size())
    }

    fn traffic(&self) -> Traffic {
        self.traffic.get()
    }

    fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }
}

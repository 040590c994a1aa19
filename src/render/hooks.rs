//! The final solve's hooks between shots: the convergence trace, progress
//! for the caller, and checkpoints (periodic, and when interrupted).

use super::options::{CheckpointPlan, RenderError};
use super::shoot::{Flags, LoopHooks};
use super::trace::{gather_whole, Extra, Trace};
use crate::checkpoint::{Checkpoint, Header};
use crate::parallel::Collectives;
use crate::solver::Solver;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Where a solve stands, for progress displays.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Shots so far.
    pub shots: u64,
    /// Unshot power fraction now.
    pub unshot_fraction: f64,
    /// Time since the solve started.
    pub elapsed: Duration,
}

/// The final solve's hooks: the trace, progress, checkpoints and interrupts.
pub struct SolveHooks<'a, 'p, 'm> {
    pub(super) comm: &'a dyn Collectives,
    pub(super) nodes: &'a [String],
    pub(super) ambient: crate::settings::AmbientTerm,
    pub(super) solve_start: Instant,
    pub(super) trace: Trace<'m>,
    pub(super) progress: &'p mut dyn FnMut(&Progress),
    pub(super) plan: Option<&'a CheckpointPlan>,
    pub(super) interrupt: Option<&'a AtomicBool>,
    pub(super) last_save: Instant,
    /// What every checkpoint says besides the state, the trace and the time.
    pub(super) header: Header,
}

impl<'m> LoopHooks<'m> for SolveHooks<'_, '_, 'm> {
    fn after_shot(&mut self, solver: &Solver<'m>, unshot_fraction: f64) {
        if self.trace.due(solver.shots()) {
            self.trace.record(
                self.comm,
                solver,
                self.nodes,
                self.ambient,
                self.solve_start,
            );
        }
        if self.comm.rank() == 0 {
            (self.progress)(&Progress {
                shots: solver.shots(),
                unshot_fraction,
                elapsed: self.solve_start.elapsed(),
            });
        }
    }

    fn flags(&self) -> Flags {
        let every = self.plan.and_then(|p| p.every);
        Flags {
            stop: self.interrupt.is_some_and(|i| i.load(Ordering::Relaxed)),
            save: self.comm.rank() == 0 && every.is_some_and(|e| self.last_save.elapsed() >= e),
        }
    }

    fn checkpoint(&mut self, solver: &Solver) -> Result<(), RenderError> {
        let started = Instant::now();
        self.last_save = started;
        let Some(plan) = self.plan else {
            return Ok(());
        };
        // Rank 0 assembles the whole state and writes it; every rank learns
        // whether that worked, so none waits for a rank that gave up.
        let all = Extra {
            element_unshot: true,
            direct: true,
        };
        let written = match gather_whole(self.comm, solver, all) {
            Some(whole) => {
                let mut header = self.header.clone();
                header.seconds = self
                    .solve_start
                    .elapsed()
                    .saturating_sub(self.trace.spent)
                    .as_secs_f64();
                header.trace = self.trace.points.clone();
                header.energy = whole.energy_record();
                let c = Checkpoint {
                    header,
                    state: whole.state(),
                };
                crate::output::write_atomic(&plan.path, &c.to_bytes()).map_err(|e| e.to_string())
            }
            _ => Ok(()),
        };
        self.comm.all_ok(written).map_err(|failed| {
            RenderError::Checkpoint(if failed.is_empty() {
                "rank 0 could not write it".into()
            } else {
                failed
                    .iter()
                    .map(|(r, m)| format!("rank {r}: {m}"))
                    .collect::<Vec<_>>()
                    .join("; ")
            })
        })?;
        if self.comm.rank() == 0 {
            log::info!(
                "saved the state after {} shots to {}",
                solver.shots(),
                plan.path.display()
            );
        }
        // Saving is bookkeeping, like the trace: not solve time.
        self.trace.spent += started.elapsed();
        Ok(())
    }
}

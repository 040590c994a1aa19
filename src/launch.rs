//! Starting a solve on the ranks a launcher started: the launcher's
//! environment, cores shared between lavapipe devices on one host, and the
//! start-up check that every rank loaded the scene and opened a device.
//! MPI itself stays in [`crate::comm`]; this module talks through
//! [`Collectives`].

use crate::parallel::Collectives;

/// How many processes the MPI launcher started, from its environment
/// (Open MPI, PMI/PMIx, MPICH's Hydra), if one did.
pub fn launched_ranks() -> Option<usize> {
    ["OMPI_COMM_WORLD_SIZE", "PMIX_SIZE", "PMI_SIZE"]
        .iter()
        .find_map(|k| std::env::var(k).ok()?.trim().parse().ok())
}

/// Under mpirun, several lavapipe devices on one host must share its cores:
/// give each rank cores / ranks-on-this-host worker threads (unless set).
/// Call before any thread starts (it sets an environment variable).
pub fn share_cores_between_ranks() {
    let local = crate::parallel::ranks_on_this_host();
    if local > 1 && std::env::var_os("LP_NUM_THREADS").is_none() {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        std::env::set_var("LP_NUM_THREADS", (cores / local).max(1).to_string());
    }
}

/// Why the ranks could not start together.
#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    /// The launcher started several processes but this one is alone.
    #[error(
        "the launcher started {launched} processes but MPI gave this one a world of {world}: \
         is this binary built against the same MPI as the mpirun that started it?"
    )]
    WorldMismatch {
        /// Processes the launcher started.
        launched: usize,
        /// Ranks MPI reports.
        world: usize,
    },
    /// Some rank failed to start; the message (on rank 0) says which and why.
    #[error("{0}")]
    Failed(String),
}

/// Refuses a world of one under a launcher that started several processes:
/// that would be N independent solves all writing the same files.
pub fn check_world(world: usize) -> Result<(), LaunchError> {
    match launched_ranks() {
        Some(launched) if launched > 1 && world != launched => {
            Err(LaunchError::WorldMismatch { launched, world })
        }
        _ => Ok(()),
    }
}

/// Every rank's start-up `outcome` (loading the scene, opening a device):
/// when any rank failed, every rank gets an error, and rank 0's names the
/// (first) failing rank and why. Nobody returns before rank 0 knows why: a
/// rank that exits early makes mpirun kill the others, rank 0's message
/// with them.
pub fn start_together<T, E: std::fmt::Display>(
    comm: &dyn Collectives,
    outcome: Result<T, E>,
) -> Result<T, LaunchError> {
    let ok = outcome.as_ref().map(|_| ()).map_err(|e| e.to_string());
    if let Err(failures) = comm.all_ok(ok) {
        let message = match failures.first() {
            Some((r, m)) if comm.size() > 1 => format!("rank {r}: {m}"),
            Some((_, m)) => m.clone(),
            None => "a rank failed to start (reported by rank 0)".to_string(),
        };
        let _ = comm.all_gather_f64(&[0.0]);
        return Err(LaunchError::Failed(message));
    }
    outcome.map_err(|e| LaunchError::Failed(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parallel::ThreadComm;

    #[test]
    fn rank_zero_says_which_rank_failed_to_start() {
        let out = ThreadComm::run(3, |c| {
            let mine: Result<u32, String> = if c.rank() == 1 {
                Err("no device".into())
            } else {
                Ok(7)
            };
            start_together(c, mine).map_err(|e| e.to_string())
        });
        assert_eq!(out[0], Err("rank 1: no device".to_string()));
        assert!(out[1].is_err() && out[2].is_err());
        let fine = ThreadComm::run(2, |c| start_together::<_, String>(c, Ok(c.rank())).ok());
        assert_eq!(fine, vec![Some(0), Some(1)]);
    }
}

//! A solver's state as it travels: each rank's share flattened for a
//! gather and assembled on rank 0, and the whole state saved in a
//! checkpoint and restored (the same bits on any rank count).

use super::Solver;
use crate::parallel::Owners;

/// A solver's whole state between shots (see [`Solver::state`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SolverState {
    /// Radiosity per element.
    pub radiosity: Vec<[f64; 3]>,
    /// Unshot radiosity per patch.
    pub unshot: Vec<[f64; 3]>,
    /// Unshot radiosity per element.
    pub element_unshot: Vec<[f64; 3]>,
    /// Shots taken.
    pub shots: u64,
    /// Shot power and landed power so far (the ambient term's retention).
    pub retention: [f64; 2],
    /// The solution's own direct part per element ([`Solver::direct`]);
    /// empty when unknown (a checkpoint from before it was kept).
    pub direct: Vec<[f64; 3]>,
    /// Per patch, whether its emission is still unshot (empty with `direct`).
    pub emission_unshot: Vec<bool>,
}

/// A saved state that does not fit the mesh it is restored on.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("the state is for {} patches and {} elements, the mesh has {} and {}", state[0], state[1], mesh[0], mesh[1])]
pub struct StateMismatch {
    /// The state's patches and elements.
    pub state: [usize; 2],
    /// The mesh's.
    pub mesh: [usize; 2],
}

impl Solver<'_> {
    /// This rank's elements' radiosities and patches' unshot radiosities, flattened
    /// (own patches in order, each followed by nothing; elements of own patches in order).
    pub fn local_state(&self) -> (Vec<f64>, Vec<f64>) {
        let mut b = Vec::new();
        let mut u = Vec::new();
        for i in self.own_patches() {
            u.extend_from_slice(&self.unshot[i]);
            let p = &self.mesh.patches[i];
            for j in p.elements.clone() {
                b.extend_from_slice(&self.radiosity[j as usize]);
            }
        }
        (b, u)
    }

    /// Installs every rank's [`Solver::local_state`] (rank order), so this
    /// solver holds the whole solution.
    pub fn assemble(&mut self, radiosity: &[Vec<f64>], unshot: &[Vec<f64>]) {
        self.vote_mut().invalidate();
        let ranks = radiosity.len();
        for (r, (b, u)) in radiosity.iter().zip(unshot).enumerate() {
            let (mut bi, mut ui) = (b.chunks_exact(3), u.chunks_exact(3));
            for i in Owners::new(self.mesh.patches.len(), ranks).patches(r, self.mesh.patches.len())
            {
                if let Some(x) = ui.next() {
                    self.unshot[i] = [x[0], x[1], x[2]];
                }
                for j in self.mesh.patches[i].elements.clone() {
                    if let Some(x) = bi.next() {
                        self.radiosity[j as usize] = [x[0], x[1], x[2]];
                    }
                }
            }
        }
        self.rank = 0;
        self.ranks = 1;
        self.owners = Owners::new(self.mesh.patches.len(), 1);
    }

    /// This rank's elements' unshot radiosity, in [`Solver::local_state`]'s
    /// element order.
    pub fn local_element_unshot(&self) -> Vec<f64> {
        self.own_elements(&self.element_unshot)
    }

    /// Installs every rank's [`Solver::local_element_unshot`] (rank order).
    pub fn assemble_element_unshot(&mut self, parts: &[Vec<f64>]) {
        self.vote_mut().invalidate();
        let mut v = std::mem::take(&mut self.element_unshot);
        self.install_elements(&mut v, parts);
        self.element_unshot = v;
    }

    /// This rank's elements' direct part ([`Solver::direct`]), in
    /// [`Solver::local_state`]'s element order.
    pub fn local_direct(&self) -> Vec<f64> {
        self.own_elements(&self.direct)
    }

    /// Installs every rank's [`Solver::local_direct`] (rank order).
    pub fn assemble_direct(&mut self, parts: &[Vec<f64>]) {
        let mut v = std::mem::take(&mut self.direct);
        self.install_elements(&mut v, parts);
        self.direct = v;
    }

    /// `values` of this rank's elements, flattened in [`Solver::local_state`]'s order.
    fn own_elements(&self, values: &[[f64; 3]]) -> Vec<f64> {
        let mut out = Vec::new();
        for i in self.own_patches() {
            for j in self.mesh.patches[i].elements.clone() {
                out.extend_from_slice(&values[j as usize]);
            }
        }
        out
    }

    /// Writes every rank's [`Solver::own_elements`] part (rank order) into `values`.
    fn install_elements(&self, values: &mut [[f64; 3]], parts: &[Vec<f64>]) {
        let ranks = parts.len();
        for (r, part) in parts.iter().enumerate() {
            let mut it = part.chunks_exact(3);
            for i in Owners::new(self.mesh.patches.len(), ranks).patches(r, self.mesh.patches.len())
            {
                for j in self.mesh.patches[i].elements.clone() {
                    if let Some(x) = it.next() {
                        values[j as usize] = [x[0], x[1], x[2]];
                    }
                }
            }
        }
    }

    /// Everything that decides the rest of the solve (of a whole, assembled
    /// solution), for a checkpoint.
    pub fn state(&self) -> SolverState {
        SolverState {
            radiosity: self.radiosity.clone(),
            unshot: self.unshot.clone(),
            element_unshot: self.element_unshot.clone(),
            shots: self.shots,
            retention: self.retention,
            direct: if self.direct_known {
                self.direct.clone()
            } else {
                Vec::new()
            },
            emission_unshot: if self.direct_known {
                self.emission_unshot.clone()
            } else {
                Vec::new()
            },
        }
    }

    /// Continues from `state` (every rank takes the whole state and keeps
    /// updating its own share). Fails when it is for another mesh.
    pub fn restore(&mut self, state: &SolverState) -> Result<(), StateMismatch> {
        self.vote_mut().invalidate();
        let (e, p) = (self.mesh.elements.len(), self.mesh.patches.len());
        if state.radiosity.len() != e || state.element_unshot.len() != e || state.unshot.len() != p
        {
            return Err(StateMismatch {
                state: [state.unshot.len(), state.radiosity.len()],
                mesh: [p, e],
            });
        }
        self.radiosity.clone_from(&state.radiosity);
        self.unshot.clone_from(&state.unshot);
        self.element_unshot.clone_from(&state.element_unshot);
        self.shots = state.shots;
        self.retention = state.retention;
        self.direct_known = state.direct.len() == e && state.emission_unshot.len() == p;
        if self.direct_known {
            self.direct.clone_from(&state.direct);
            self.emission_unshot.clone_from(&state.emission_unshot);
        } else {
            // An old checkpoint: the image falls back to tracing each
            // element's direct light; emitters that shot do not shoot
            // their emission again.
            self.direct = vec![[0.0; 3]; e];
            if state.shots > 0 {
                self.emission_unshot = vec![false; p];
            }
        }
        Ok(())
    }

    /// Sets the shot count (after assembling a distributed solution).
    pub fn set_shots(&mut self, shots: u64) {
        self.shots = shots;
    }
}

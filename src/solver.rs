//! Progressive refinement radiosity (Cohen, Chen, Wallace & Greenberg 1988),
//! exactly as DESIGN.md section 2 states it:
//!
//! 1. pick the patch i with the largest unshot power dB_i * A_i;
//! 2. get the form factor F_ij from i to every element j (from a [`FormFactorSource`]);
//! 3. give each element dB_j = rho_j * dB_i * F_ij * A_i / A_j, added to B_j and,
//!    area-weighted, to its patch's unshot store;
//! 4. set dB_i = 0; stop when the unshot power is a small fraction of the emitted power.
//!
//! The solver knows nothing of GPUs or ranks: form factors arrive as sparse
//! (element, F) pairs.

use crate::mesh::Mesh;

/// Anything that can produce the form factors from a shooter patch to the elements.
pub trait FormFactorSource {
    /// The error a shot can fail with.
    type Error;
    /// Fills `out` with (element, F_ij) pairs for shooter patch `shooter`,
    /// shooting from `region` (see [`Solver::shooting_region`]), sorted by element.
    fn form_factors(
        &mut self,
        shooter: u32,
        region: &ShotRegion,
        out: &mut Vec<(u32, f64)>,
    ) -> Result<(), Self::Error>;
}

/// How a shooter patch shoots: where its hemisphere goes, and how its unshot
/// radiosity is spread over its elements.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ShotRegion {
    /// The hemisphere's centre (a point of the patch).
    pub centre: glam::Vec3,
    /// Per element of the patch (in order), its unshot radiosity over the
    /// patch's (summed over RGB): the patch shoots each element's own share,
    /// so a coarse shooter keeps the detail its elements received (hidden
    /// elements shoot nothing). Empty when all are equal (the whole patch
    /// shoots uniformly).
    pub weights: Vec<f64>,
}

/// When to stop shooting.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct StopRule {
    /// Stop once unshot power / emitted power is at most this.
    pub threshold: f64,
    /// Stop after this many shots regardless.
    pub max_shots: u64,
}

impl Default for StopRule {
    fn default() -> Self {
        Self {
            threshold: 1e-3,
            max_shots: 100_000,
        }
    }
}

/// What one shot did.
#[derive(Clone, Copy, Debug)]
pub struct Shot {
    /// The patch that shot.
    pub shooter: u32,
    /// Its unshot power before the shot (sum over RGB), W.
    pub power: f64,
    /// Sum of F_ij over all elements (1 in a closed scene).
    pub form_factor_sum: f64,
}

/// A rank's proposal for the next shooter: its patch with the most unshot power.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// The patch.
    pub patch: u32,
    /// Its unshot power (sum over RGB), W.
    pub power: f64,
    /// Its unshot radiosity dB.
    pub unshot: [f64; 3],
    /// Where its hemisphere goes (see [`Solver::shooting_region`]).
    pub centre: glam::Vec3,
    /// Whether its elements' unshot radiosities differ (see [`ShotRegion::weights`]).
    pub weighted: bool,
}

impl Candidate {
    /// The global shooter: the largest power, the lowest patch index on ties
    /// (the same answer whatever the order of `candidates`).
    pub fn best(candidates: impl IntoIterator<Item = Candidate>) -> Option<Candidate> {
        candidates
            .into_iter()
            .fold(None, |best: Option<Candidate>, c| match best {
                Some(b) if b.power > c.power || (b.power == c.power && b.patch < c.patch) => {
                    Some(b)
                }
                _ => Some(c),
            })
    }
}

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
}

/// Fixed-point scale of unshot power as a fraction of the emitted power, so
/// the stop rule sums exactly and ranks agree bit for bit.
pub const UNSHOT_ONE: f64 = (1u64 << 40) as f64;

/// Radiosity state over a mesh, or over one rank's share of it: patch k
/// belongs to rank k mod ranks, and an element to its patch's rank.
pub struct Solver<'m> {
    mesh: &'m Mesh,
    rank: usize,
    ranks: usize,
    /// Radiosity B per element, W/m^2 per channel.
    radiosity: Vec<[f64; 3]>,
    /// Unshot radiosity dB per patch.
    unshot: Vec<[f64; 3]>,
    /// Unshot radiosity per element (this rank's elements): how the patch's
    /// unshot radiosity is spread over it.
    element_unshot: Vec<[f64; 3]>,
    emitted_power: f64,
    shots: u64,
    /// Shot power so far, and landed power so far (see [`Solver::note_retention`]).
    retention: [f64; 2],
    ff: Vec<(u32, f64)>,
}

fn power(b: &[f64; 3], area: f64) -> f64 {
    (b[0] + b[1] + b[2]) * area
}

impl<'m> Solver<'m> {
    /// Starts with B = dB = E (the emitters' exitance) everywhere.
    pub fn new(mesh: &'m Mesh) -> Self {
        Self::partitioned(mesh, 0, 1)
    }

    /// The share of rank `rank` of `ranks` (it holds every patch but updates only its own).
    pub fn partitioned(mesh: &'m Mesh, rank: usize, ranks: usize) -> Self {
        let radiosity: Vec<[f64; 3]> = mesh
            .elements
            .iter()
            .map(|e| mesh.polygons[e.polygon as usize].exitance)
            .collect();
        let unshot: Vec<[f64; 3]> = mesh
            .patches
            .iter()
            .map(|p| mesh.polygons[p.polygon as usize].exitance)
            .collect();
        let emitted_power = unshot
            .iter()
            .zip(&mesh.patches)
            .map(|(b, p)| power(b, p.area))
            .sum();
        Self {
            mesh,
            rank,
            ranks: ranks.max(1),
            element_unshot: radiosity.clone(),
            radiosity,
            unshot,
            emitted_power,
            shots: 0,
            retention: [0.0; 2],
            ff: Vec::new(),
        }
    }

    /// The mesh this solver works on.
    pub fn mesh(&self) -> &'m Mesh {
        self.mesh
    }

    /// Radiosity per element (without the ambient term).
    pub fn radiosity(&self) -> &[[f64; 3]] {
        &self.radiosity
    }

    /// Shots taken so far.
    pub fn shots(&self) -> u64 {
        self.shots
    }

    /// Total emitted power (sum over RGB), W.
    pub fn emitted_power(&self) -> f64 {
        self.emitted_power
    }

    /// Whether this rank owns `patch`.
    pub fn owns(&self, patch: u32) -> bool {
        patch as usize % self.ranks == self.rank
    }

    fn own_patches(&self) -> impl Iterator<Item = usize> + '_ {
        (self.rank..self.mesh.patches.len()).step_by(self.ranks)
    }

    /// This rank's unshot power over the emitted power, in [`UNSHOT_ONE`] fixed point.
    pub fn local_unshot_fixed(&self) -> u64 {
        if self.emitted_power <= 0.0 {
            return 0;
        }
        self.own_patches()
            .map(|i| {
                (power(&self.unshot[i], self.mesh.patches[i].area) / self.emitted_power
                    * UNSHOT_ONE)
                    .round() as u64
            })
            .sum()
    }

    /// Unshot power / emitted power (one rank: this solver's; see [`Solver::local_unshot_fixed`]).
    pub fn unshot_fraction(&self) -> f64 {
        self.local_unshot_fixed() as f64 / UNSHOT_ONE
    }

    /// Whether the stop rule is met, given the unshot fraction over all ranks.
    pub fn done_at(&self, rule: &StopRule, unshot_fraction: f64) -> bool {
        self.shots >= rule.max_shots || unshot_fraction <= rule.threshold
    }

    /// Whether the stop rule is met (one rank).
    pub fn done(&self, rule: &StopRule) -> bool {
        self.done_at(rule, self.unshot_fraction())
    }

    /// This rank's patch with the largest unshot power (lowest index on ties), if any has some.
    pub fn local_candidate(&self) -> Option<Candidate> {
        Candidate::best(self.own_patches().filter_map(|i| {
            let w = power(&self.unshot[i], self.mesh.patches[i].area);
            (w > 0.0).then_some(Candidate {
                patch: i as u32,
                power: w,
                unshot: self.unshot[i],
                centre: glam::Vec3::ZERO,
                weighted: false,
            })
        }))
        .map(|c| {
            let region = self.shooting_region(c.patch);
            Candidate {
                centre: region.centre,
                weighted: !region.weights.is_empty(),
                ..c
            }
        })
    }

    /// How patch `patch` shoots. The hemisphere sits at the patch's centre,
    /// unless some of its elements have no radiosity at all (hidden, e.g. under
    /// an object resting on the patch's polygon): then at the area-weighted
    /// centre of the others, since a hemisphere at a hidden point would see
    /// nothing. Each element shoots its own unshot radiosity (the weights).
    /// Needs this rank to own `patch`.
    pub fn shooting_region(&self, patch: u32) -> ShotRegion {
        let p = &self.mesh.patches[patch as usize];
        let total: f64 = self.unshot[patch as usize].iter().sum();
        let share = |j: u32| self.element_unshot[j as usize].iter().sum::<f64>() / total;
        let first = share(p.elements.start);
        let weights = if total > 0.0 && p.elements.clone().any(|j| share(j) != first) {
            p.elements.clone().map(share).collect()
        } else {
            Vec::new()
        };
        let lit = |j: &u32| self.radiosity[*j as usize].iter().any(|&b| b > 0.0);
        let centre = if p.elements.clone().all(|j| lit(&j)) {
            p.centre
        } else {
            let lit_elements = p.elements.clone().filter(lit);
            crate::mesh::area_centroid(lit_elements.map(|j| &self.mesh.elements[j as usize]))
                .unwrap_or(p.centre)
        };
        ShotRegion { centre, weights }
    }

    /// The patch with the largest unshot power (one rank).
    pub fn select_shooter(&self) -> Option<u32> {
        self.local_candidate().map(|c| c.patch)
    }

    /// Distributes the unshot radiosity of `shooter` through the form factors
    /// `ff`, updating only this rank's elements.
    pub fn shoot_candidate(&mut self, shooter: &Candidate, ff: &[(u32, f64)]) -> Shot {
        let mesh = self.mesh;
        let i = shooter.patch as usize;
        if self.owns(shooter.patch) {
            self.unshot[i] = [0.0; 3];
            for k in mesh.patches[i].elements.clone() {
                self.element_unshot[k as usize] = [0.0; 3];
            }
        }
        let (db, area) = (shooter.unshot, mesh.patches[i].area);
        let mut form_factor_sum = 0.0;
        for &(j, f) in ff {
            form_factor_sum += f;
            let el = &mesh.elements[j as usize];
            if !self.owns(el.patch) {
                continue;
            }
            let rho = mesh.polygons[el.polygon as usize].reflectance;
            let scale = f * area / el.area;
            let patch_share = el.area / mesh.patches[el.patch as usize].area;
            for c in 0..3 {
                let d = rho[c] * db[c] * scale;
                self.radiosity[j as usize][c] += d;
                self.element_unshot[j as usize][c] += d;
                self.unshot[el.patch as usize][c] += d * patch_share;
            }
        }
        self.shots += 1;
        Shot {
            shooter: shooter.patch,
            power: shooter.power,
            form_factor_sum,
        }
    }

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
        let ranks = radiosity.len();
        for (r, (b, u)) in radiosity.iter().zip(unshot).enumerate() {
            let (mut bi, mut ui) = (b.chunks_exact(3), u.chunks_exact(3));
            for i in (r..self.mesh.patches.len()).step_by(ranks) {
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
    }

    /// This rank's elements' unshot radiosity, in [`Solver::local_state`]'s
    /// element order.
    pub fn local_element_unshot(&self) -> Vec<f64> {
        let mut out = Vec::new();
        for i in self.own_patches() {
            for j in self.mesh.patches[i].elements.clone() {
                out.extend_from_slice(&self.element_unshot[j as usize]);
            }
        }
        out
    }

    /// Installs every rank's [`Solver::local_element_unshot`] (rank order).
    pub fn assemble_element_unshot(&mut self, parts: &[Vec<f64>]) {
        let ranks = parts.len();
        for (r, part) in parts.iter().enumerate() {
            let mut it = part.chunks_exact(3);
            for i in (r..self.mesh.patches.len()).step_by(ranks) {
                for j in self.mesh.patches[i].elements.clone() {
                    if let Some(x) = it.next() {
                        self.element_unshot[j as usize] = [x[0], x[1], x[2]];
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
        }
    }

    /// Continues from `state` (every rank takes the whole state and keeps
    /// updating its own share). Fails when it is for another mesh.
    pub fn restore(&mut self, state: &SolverState) -> Result<(), String> {
        let (e, p) = (self.mesh.elements.len(), self.mesh.patches.len());
        if state.radiosity.len() != e || state.element_unshot.len() != e || state.unshot.len() != p
        {
            return Err(format!(
                "the state is for {} patches and {} elements, the mesh has {p} and {e}",
                state.unshot.len(),
                state.radiosity.len()
            ));
        }
        self.radiosity.clone_from(&state.radiosity);
        self.unshot.clone_from(&state.unshot);
        self.element_unshot.clone_from(&state.element_unshot);
        self.shots = state.shots;
        self.retention = state.retention;
        Ok(())
    }

    /// Sets the shot count (after assembling a distributed solution).
    pub fn set_shots(&mut self, shots: u64) {
        self.shots = shots;
    }

    /// Distributes the shooter's unshot radiosity through the form factors `ff` (one rank).
    pub fn shoot(&mut self, shooter: u32, ff: &[(u32, f64)]) -> Shot {
        let i = shooter as usize;
        let unshot = self.unshot[i];
        let c = Candidate {
            patch: shooter,
            power: power(&unshot, self.mesh.patches[i].area),
            unshot,
            centre: glam::Vec3::ZERO,
            weighted: false,
        };
        let shot = self.shoot_candidate(&c, ff);
        self.note_retention(shot.power, shot.form_factor_sum);
        shot
    }

    /// One whole shot: select, get form factors, distribute. `None` when nothing is left to shoot.
    pub fn step<S: FormFactorSource>(&mut self, source: &mut S) -> Result<Option<Shot>, S::Error> {
        let Some(shooter) = self.select_shooter() else {
            return Ok(None);
        };
        let mut ff = std::mem::take(&mut self.ff);
        source.form_factors(shooter, &self.shooting_region(shooter), &mut ff)?;
        let shot = self.shoot(shooter, &ff);
        self.ff = ff;
        Ok(Some(shot))
    }

    /// Records that a shot of `power` landed the fraction `landed` of it on
    /// the scene (the sum of its form factors over all elements; below 1 where
    /// light escapes an open scene). The ambient term uses the power-weighted mean.
    pub fn note_retention(&mut self, power: f64, landed: f64) {
        if power > 0.0 && landed.is_finite() {
            self.retention[0] += power;
            self.retention[1] += power * landed.clamp(0.0, 1.0);
        }
    }

    /// The power-weighted mean fraction of shot power that landed (1 before any shot).
    pub fn retention(&self) -> f64 {
        if self.retention[0] > 0.0 {
            self.retention[1] / self.retention[0]
        } else {
            1.0
        }
    }

    /// Takes over `other`'s retention record (for a solver assembled from ranks).
    pub fn copy_retention(&mut self, other: &Solver) {
        self.retention = other.retention;
    }

    /// The ambient term (Cohen et al. 1988), for an open scene: the unshot
    /// power U spread uniformly over the area A, of which the fraction f that
    /// shots have been seen to land ([`Solver::retention`]) lands each bounce:
    /// U f / (A (1 - rho_avg f)) per channel (Cohen's 1 / (1 - rho_avg) in a
    /// closed scene). It estimates the light not yet shot; it is kept apart
    /// from [`Solver::radiosity`] and added by [`Solver::display_radiosity`].
    pub fn ambient(&self) -> [f64; 3] {
        let f = self.retention();
        let mesh = self.mesh;
        let total_area = mesh.total_area();
        let mut out = [0.0; 3];
        if total_area <= 0.0 {
            return out;
        }
        for c in 0..3 {
            let unshot: f64 = self
                .unshot
                .iter()
                .zip(&mesh.patches)
                .map(|(b, p)| b[c] * p.area)
                .sum();
            let rho: f64 = mesh
                .elements
                .iter()
                .map(|e| mesh.polygons[e.polygon as usize].reflectance[c] * e.area)
                .sum::<f64>()
                / total_area;
            out[c] = unshot * f / total_area / (1.0 - rho * f).max(1e-3);
        }
        out
    }

    /// Radiosity for display: B, plus rho times the ambient term when `ambient` is set.
    pub fn display_radiosity(&self, ambient: bool) -> Vec<[f64; 3]> {
        let amb = if ambient { self.ambient() } else { [0.0; 3] };
        self.radiosity
            .iter()
            .zip(&self.mesh.elements)
            .map(|(b, e)| {
                let rho = self.mesh.polygons[e.polygon as usize].reflectance;
                [
                    b[0] + rho[0] * amb[0],
                    b[1] + rho[1] * amb[1],
                    b[2] + rho[2] * amb[2],
                ]
            })
            .collect()
    }
}

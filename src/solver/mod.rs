//! Progressive refinement radiosity (Cohen, Chen, Wallace & Greenberg 1988),
//! exactly as DESIGN.md section 2 states it:
//!
//! 1. pick the patch i with the largest unshot power dB_i * A_i;
//! 2. get the form factor F_ij from i to every element j (from a [`FormFactorSource`]);
//! 3. shoot S_i = dB_i: each element gets dB_j = rho_j * S_i * F_ij * A_i / A_j,
//!    added to B_j and, area-weighted, to its patch's unshot store;
//! 4. set dB_i = 0; stop when the unshot power is a small fraction of the
//!    emitted power.
//!
//! Each element of the shooter shoots its own share, per channel. The solver
//! knows nothing of GPUs or ranks: form factors arrive as sparse [`Transfer`]s.

use crate::lit_mesh::LitMesh;
use crate::mesh::Mesh;
use crate::numeric::prefetch;
use crate::parallel::Owners;

mod display;
mod energy;
mod setup;
use setup::{abs_power, patch_share, power, takes_ambient, PerElement, Receiving};
mod state;
mod vote;
use crate::settings::AmbientTerm;
pub use crate::shot::{FormFactorSource, ShotRegion, Transfer};
pub use energy::Retained;
pub use state::{SolverState, StateMismatch};

/// When to stop shooting.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct StopRule {
    /// Stop once unshot power (of |dB|) / emitted power is at most this.
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
    /// Its unshot power before the shot (of |dB|, sum over RGB), W.
    pub power: f64,
    /// The power it shot (sum over RGB), W.
    pub shot_power: f64,
    /// Sum of F_ij over the transfers the shot was given: over all
    /// elements on one rank (1 in a closed scene), over the rank's own
    /// where a source gives only those (as the transport rows do).
    pub form_factor_sum: f64,
    /// What it landed on this rank's elements (the sum of their form
    /// factors) and the power it delivered to them over the emitted power,
    /// both in [`UNSHOT_ONE`] fixed point (see [`landing_share`]).
    pub landed: (u64, i64),
}

/// What transfer `t` of a shot from a patch of area `area` lands (its form
/// factor) and delivers (its power over the `emitted` power), each in
/// [`UNSHOT_ONE`] fixed point, rounded on its own: sums over any split of
/// the elements between ranks agree.
pub fn landing_share(t: &Transfer, area: f64, emitted: f64) -> (u64, i64) {
    let landed = crate::numeric::round_u64(t.form_factor.clamp(0.0, 1.0) * UNSHOT_ONE);
    let delivered = if emitted > 0.0 {
        let w = (t.radiosity[0] + t.radiosity[1] + t.radiosity[2]) * area;
        crate::numeric::round_i64(w / emitted * UNSHOT_ONE)
    } else {
        0
    };
    (landed, delivered)
}

/// A rank's proposal for the next shooter: its patch with the most unshot power.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// The patch.
    pub patch: u32,
    /// Its unshot power (of |dB|, sum over RGB), W.
    pub power: f64,
    /// Its unshot radiosity dB.
    pub unshot: [f64; 3],
    /// Where its hemisphere goes (see [`Solver::shooting_region`]).
    pub centre: glam::Vec3,
    /// Whether its elements shoot different radiosities (see [`ShotRegion::elements`]).
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

/// Where a solution's emitted power has gone, W (sum over RGB). Every shot
/// takes its power from the unshot store and delivers it to the elements
/// it reaches, which reflect part of it back into the store and absorb the
/// rest; what meets the back of a one-sided surface is absorbed there
/// (glTF's one-sided surfaces are black behind, as in a path tracer); what
/// reaches nothing has left the scene. So emitted = absorbed + back_faces +
/// unshot + escaped; in a closed scene nothing escapes, and `balance` =
/// (absorbed + back_faces + unshot) / emitted is 1.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Energy {
    /// Power emitted.
    pub emitted: f64,
    /// Power absorbed by the elements.
    pub absorbed: f64,
    /// Power absorbed by the backs of one-sided surfaces.
    pub back_faces: f64,
    /// Power still unshot.
    pub unshot: f64,
    /// Power shot that reached no element: it left the scene (or, in a
    /// closed scene, was lost or created by the form factors).
    pub escaped: f64,
    /// (absorbed + back_faces + unshot) / emitted: 1 in a closed scene.
    pub balance: f64,
}

/// The signed unshot power per channel, over the emitted power, in
/// [`UNSHOT_ONE`] fixed point (so ranks sum it exactly): what the ambient
/// term is computed from.
pub type NetUnshot = [i64; 3];

/// Fixed-point scale of unshot power as a fraction of the emitted power, so
/// the stop rule sums exactly and ranks agree bit for bit.
pub const UNSHOT_ONE: f64 = (1u64 << 40) as f64;

/// Radiosity state over a mesh, or over one rank's share of it: patches
/// belong to ranks as [`Owners`] deals them, and an element to its
/// patch's rank.
pub struct Solver<'m> {
    mesh: &'m LitMesh,
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
    /// Power shot, power delivered to elements, and power absorbed by back
    /// faces so far, signed, sum over RGB (see [`Solver::note_energy`]).
    energy: [f64; 3],
    /// Area-weighted mean reflectance (the ambient term's rho_avg).
    mean_reflectance: [f64; 3],
    /// The mesh's area.
    total_area: f64,
    /// The solution's own direct part per element (W/m^2 per channel): what
    /// it reflects of the emitters' first shots of their emission. The
    /// camera image replaces it with direct light traced exactly.
    direct: Vec<[f64; 3]>,
    /// Per patch, whether its emission is still unshot (every rank knows:
    /// every rank sees every shot).
    emission_unshot: Vec<bool>,
    /// Whether `direct` is known (not after resuming an old checkpoint).
    direct_known: bool,
    /// Per patch, its area: the scans of every shot read this, not the
    /// patch records (Sponza: 13 MB a scan instead of 32).
    patch_area: Vec<f64>,
    /// Per element, what a shot's update reads of it (see [`Receiving`]);
    /// only this rank's elements' are set.
    receiving: Vec<Receiving>,
    /// Per element (every rank's), its patch: who owns it.
    element_patch: Vec<u32>,
    /// Which rank owns which patch (`ranks` of them).
    owners: Owners,
    /// The vote for the next shooter, kept up to date (see [`vote`]); a
    /// lock only because [`Solver::local_vote`] reads through `&self`.
    vote: std::sync::Mutex<vote::Vote>,
}

impl<'m> Solver<'m> {
    /// Starts with B = dB = E (the emitters' exitance) everywhere.
    pub fn new(mesh: &'m LitMesh) -> Self {
        Self::partitioned(mesh, 0, 1)
    }

    /// The share of rank `rank` of `ranks` (it holds every patch but updates only its own).
    pub fn partitioned(mesh: &'m LitMesh, rank: usize, ranks: usize) -> Self {
        let owners = Owners::new(mesh.patches.len(), ranks);
        // Traced emitters have shot their emission (`receive_lights`).
        let traced = mesh.emitter_field.is_some();
        let PerElement {
            exitance: radiosity,
            element_unshot,
            receiving,
            element_patch,
            mean_reflectance,
            ambient_area,
        } = PerElement::of(mesh, owners, rank, traced);
        let unshot: Vec<[f64; 3]> = (0..mesh.patches.len())
            .map(|i| {
                if traced {
                    [0.0; 3]
                } else {
                    mesh.patch_exitance(i)
                }
            })
            .collect();
        let emitted_power = mesh.source_power();
        let mut solver = Self {
            mesh,
            rank,
            ranks: ranks.max(1),
            owners,
            element_unshot,
            radiosity,
            unshot,
            emitted_power,
            shots: 0,
            retention: [0.0; 2],
            energy: [0.0; 3],
            mean_reflectance,
            total_area: ambient_area,
            direct: vec![[0.0; 3]; mesh.elements.len()],
            emission_unshot: mesh
                .patches
                .iter()
                .map(|p| !traced && mesh.polygons[p.polygon as usize].emits())
                .collect(),
            direct_known: true,
            patch_area: mesh.patches.iter().map(|p| p.area).collect(),
            receiving,
            element_patch,
            vote: Default::default(),
        };
        solver.receive_lights();
        solver
    }

    /// The first shot, of the lights, the sky (`lights`) and the traced
    /// emitters (`direct::EmitterField`): each element reflects rho E of
    /// what they deliver, into its radiosity and its patch's unshot store;
    /// the lights' and emitters' part is direct light (the camera image
    /// traces it again), the sky's is not. Every rank does it whole, as
    /// every rank starts from the emitters' exitance.
    fn receive_lights(&mut self) {
        let mesh = self.mesh;
        let field = &mesh.light_field;
        let traced = mesh.emitter_field.as_ref();
        if field.is_empty() && traced.is_none() {
            return;
        }
        let zero = [0.0; 3];
        for (j, e) in mesh.elements.iter().enumerate() {
            let rho = e.reflectance;
            let share = patch_share(mesh, e);
            let mut lights = *field.direct.get(j).unwrap_or(&zero);
            let sky = *field.sky.get(j).unwrap_or(&zero);
            if let Some(t) = traced {
                (0..3).for_each(|c| lights[c] += t.irradiance[j][c]);
            }
            // Every patch's store, but only this rank's elements (the
            // others' are never read here).
            let own = self.owners.of(e.patch) == self.rank;
            for c in 0..3 {
                let d = rho[c] * (lights[c] + sky[c]);
                if own {
                    self.direct[j][c] += rho[c] * lights[c];
                    self.radiosity[j][c] += d;
                    self.element_unshot[j][c] += d;
                }
                self.unshot[e.patch as usize][c] += d * share;
            }
        }
        // Shot as one: what missed the elements left the scene (or met
        // the backs of one-sided surfaces, which rays do not tell apart).
        let (power, delivered) = traced.map_or((0.0, 0.0), |t| (t.power, t.delivered));
        self.note_energy(field.emitted + power, field.delivered + delivered, 0.0);
        self.vote_mut().invalidate();
    }

    /// The mesh this solver works on.
    pub fn mesh(&self) -> &'m LitMesh {
        self.mesh
    }

    /// Shots taken so far.
    pub fn shots(&self) -> u64 {
        self.shots
    }

    /// Total emitted power (sum over RGB), W.
    pub fn emitted_power(&self) -> f64 {
        self.emitted_power
    }

    /// The rank that owns `patch`.
    pub fn patch_rank(&self, patch: u32) -> usize {
        self.owners.of(patch)
    }

    /// Whether this rank owns `patch`.
    pub fn owns(&self, patch: u32) -> bool {
        self.patch_rank(patch) == self.rank
    }

    /// The rank that updates element `element` (its patch's owner).
    pub fn element_rank(&self, element: u32) -> usize {
        self.owners.of(self.element_patch[element as usize])
    }

    fn own_patches(&self) -> impl Iterator<Item = usize> {
        self.owners.patches(self.rank, self.mesh.patches.len())
    }

    /// This rank's unshot power (of |dB|) over the emitted power, in
    /// [`UNSHOT_ONE`] fixed point.
    pub fn local_unshot_fixed(&self) -> u64 {
        self.local_vote().0
    }

    /// A power over the emitted power, in [`UNSHOT_ONE`] fixed point.
    fn to_fixed(&self, power: f64) -> u64 {
        if self.emitted_power <= 0.0 {
            return 0;
        }
        crate::numeric::round_u64(power / self.emitted_power * UNSHOT_ONE)
    }

    /// [`Solver::local_unshot_fixed`] and [`Solver::local_candidate`] in one
    /// scan of the patches (what every shot's vote needs).
    pub fn local_vote(&self) -> (u64, Option<Candidate>) {
        let patches = self.mesh.patches.len();
        let leaves = self.owners.count(self.rank, patches);
        let key = (self.rank, self.ranks, patches);
        // Leaf k is the rank's k-th own patch, in increasing order, so the
        // first of equal powers wins (the lowest index, as
        // `Candidate::best` breaks ties).
        let (fixed, best) =
            self.vote
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .refresh(key, leaves, |k| {
                    let w = self.patch_power(self.owners.at(self.rank, k));
                    (w, self.to_fixed(w))
                });
        (
            fixed,
            best.map(|(k, w)| self.patch_candidate(self.owners.at(self.rank, k), w)),
        )
    }

    /// Notes that patch `patch`'s residual changed, if it is this rank's
    /// (for the vote; a free function so a loop can hold the vote while it
    /// writes the other fields).
    fn touch(vote: &mut vote::Vote, rank: usize, owners: Owners, patch: usize) {
        if owners.of(patch as u32) == rank {
            vote.touch(owners.index(patch));
        }
    }

    /// [`Solver::touch`] on this solver's vote.
    fn touch_patch(&mut self, patch: usize) {
        let (rank, owners) = (self.rank, self.owners);
        Self::touch(self.vote_mut(), rank, owners, patch);
    }

    /// The vote, for writing (no lock: `&mut self`).
    fn vote_mut(&mut self) -> &mut vote::Vote {
        self.vote.get_mut().unwrap_or_else(|e| e.into_inner())
    }

    /// How much patch `i`'s residual still matters: its unshot power (sum
    /// over RGB, W).
    fn patch_power(&self, i: usize) -> f64 {
        abs_power(&self.unshot[i], self.patch_area[i])
    }

    /// Whether patch `patch` still holds its emission unshot (every rank knows).
    pub fn emission_unshot(&self, patch: u32) -> bool {
        self.emission_unshot[patch as usize]
    }

    /// The signed unshot power of this rank's patches among `patches`, per
    /// channel, as a fraction of the emitted power in [`UNSHOT_ONE`] fixed
    /// point (summed over ranks it is theirs, whatever the ranks).
    pub fn net_unshot_of(&self, patches: &[u32]) -> NetUnshot {
        self.net_unshot_over(
            patches
                .iter()
                .map(|&i| i as usize)
                .filter(|&i| self.owns(i as u32)),
        )
    }

    /// The signed unshot power of `patches` per channel, over the emitted
    /// power in [`UNSHOT_ONE`] fixed point, each patch rounded on its own
    /// (so sums over ranks do not depend on how patches are dealt).
    fn net_unshot_over(&self, patches: impl Iterator<Item = usize>) -> NetUnshot {
        let mut out = [0i64; 3];
        if self.emitted_power <= 0.0 {
            return out;
        }
        for i in patches {
            let (b, a) = (&self.unshot[i], self.patch_area[i]);
            for (o, x) in out.iter_mut().zip(b) {
                *o += crate::numeric::round_i64(x * a / self.emitted_power * UNSHOT_ONE);
            }
        }
        out
    }

    /// Marks this rank's patches among `patches` as having shot all they
    /// held (a group shooting as one: see `render::shoot`).
    pub fn clear_unshot(&mut self, patches: &[u32]) {
        let mesh = self.mesh;
        for &i in patches {
            if !self.owns(i) {
                continue;
            }
            self.touch_patch(i as usize);
            self.unshot[i as usize] = [0.0; 3];
            for k in mesh.patches[i as usize].elements.clone() {
                self.element_unshot[k as usize] = [0.0; 3];
            }
        }
    }

    /// This rank's signed unshot power per channel (see [`NetUnshot`]); the
    /// sum over ranks is the whole solution's.
    pub fn local_net_unshot(&self) -> NetUnshot {
        self.net_unshot_over(self.own_patches())
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

    /// This rank's `k` patches with the largest unshot power (the lowest
    /// index first on ties), strongest first: its part of a batch of shots.
    pub fn local_top(&self, k: usize) -> Vec<Candidate> {
        let _ = self.local_vote();
        let top = self.vote.lock().unwrap_or_else(|e| e.into_inner()).top(k);
        top.into_iter()
            .map(|(leaf, w)| self.patch_candidate(self.owners.at(self.rank, leaf), w))
            .collect()
    }

    /// This rank's patch with the largest unshot power (lowest index on ties), if any has some.
    pub fn local_candidate(&self) -> Option<Candidate> {
        self.local_vote().1
    }

    /// The candidate of patch `i`, whose power is `power`.
    fn patch_candidate(&self, i: usize, power: f64) -> Candidate {
        let p = &self.mesh.patches[i];
        let first = self.element_unshot[p.elements.start as usize];
        Candidate {
            patch: i as u32,
            power,
            unshot: self.unshot[i],
            centre: self.shooting_centre(i as u32),
            // Elements shoot differently when their unshot radiosities differ.
            weighted: p
                .elements
                .clone()
                .any(|j| self.element_unshot[j as usize] != first),
        }
    }

    /// Whether element `j` has received (or emits) any light.
    fn lit(&self, j: u32) -> bool {
        self.radiosity[j as usize].iter().any(|&b| b > 0.0)
    }

    /// Where patch `patch`'s hemisphere goes: the patch's centre, unless some
    /// of its elements have no radiosity at all (hidden, e.g. under an object
    /// resting on the patch's polygon) or the centre lies inside a closed
    /// solid (under a box that covers part of the patch): then
    /// [`Mesh::open_centre`](crate::mesh::Mesh::open_centre) of its lit
    /// elements. A hemisphere at a hidden point sees nothing but back
    /// faces, and the patch's light would be lost on them.
    fn shooting_centre(&self, patch: u32) -> glam::Vec3 {
        let mesh = self.mesh;
        let p = &mesh.patches[patch as usize];
        let all_lit = p.elements.clone().all(|j| self.lit(j));
        if all_lit && !mesh.enclosed(p.centre, p.polygon) {
            return p.centre;
        }
        let lit = p
            .elements
            .clone()
            .filter(|&j| self.lit(j))
            .map(|j| &mesh.elements[j as usize]);
        mesh.open_centre(p.polygon, lit.clone())
            .or_else(|| crate::mesh::area_centroid(lit))
            .unwrap_or(p.centre)
    }

    /// How `candidate` shoots, for a rank that knows only the candidate
    /// (uniform shooters; a weighted one's elements come from its owner's
    /// [`Solver::shooting_region`]).
    pub fn candidate_region(&self, candidate: &Candidate) -> ShotRegion {
        ShotRegion {
            centre: candidate.centre,
            power: candidate.power,
            shoot: candidate.unshot,
            elements: Vec::new(),
        }
    }

    /// How patch `patch` shoots (see [`Solver::shooting_centre`]): each element
    /// its own unshot radiosity. Needs this rank to own `patch`.
    pub fn shooting_region(&self, patch: u32) -> ShotRegion {
        let p = &self.mesh.patches[patch as usize];
        let elements: Vec<[f64; 3]> = p
            .elements
            .clone()
            .map(|j| self.element_unshot[j as usize])
            .collect();
        let mut shoot = [0.0; 3];
        for (j, s) in p.elements.clone().zip(&elements) {
            let share = self.mesh.elements[j as usize].area / p.area;
            for c in 0..3 {
                shoot[c] += s[c] * share;
            }
        }
        ShotRegion::new(
            self.shooting_centre(patch),
            self.patch_power(patch as usize),
            shoot,
            elements,
        )
    }

    /// Shoots `region` from `shooter` through the transfers `ff`, updating
    /// only this rank's elements (and the shooter's residual, on its owner).
    pub fn shoot_candidate(
        &mut self,
        shooter: &Candidate,
        region: &ShotRegion,
        ff: &[Transfer],
    ) -> Shot {
        let direct_share = self.take_shooter(shooter, region);
        self.land(shooter, region, ff, direct_share)
    }

    /// The first half of [`Solver::shoot_candidate`]: empties the shooter's store and returns the share of
    /// the shot that is its own emission, per channel. A batch of shots
    /// takes every shooter before it lands any, so light one of them lands
    /// on another stays.
    pub fn take_shooter(&mut self, shooter: &Candidate, region: &ShotRegion) -> [f64; 3] {
        let mesh = self.mesh;
        let i = shooter.patch as usize;
        let p = &mesh.patches[i];
        self.touch_patch(i);
        if self.owns(shooter.patch) {
            self.unshot[i] = [0.0; 3];
            for k in p.elements.clone() {
                self.element_unshot[k as usize] = [0.0; 3];
            }
        }
        // The share of this shot that is the shooter's own emission (its
        // first shot carries all of it), per channel.
        let emission = mesh.patch_exitance(i);
        if std::mem::take(&mut self.emission_unshot[i]) {
            [0, 1, 2].map(|c| {
                if region.shoot[c] > 0.0 {
                    (emission[c] / region.shoot[c]).min(1.0)
                } else {
                    0.0
                }
            })
        } else {
            [0.0; 3]
        }
    }

    /// The second half of [`Solver::shoot_candidate`]: lands the shot on
    /// this rank's elements through the transfers `ff`, `direct_share` of
    /// it (from [`Solver::take_shooter`]) being the shooter's emission.
    pub fn land(
        &mut self,
        shooter: &Candidate,
        region: &ShotRegion,
        ff: &[Transfer],
        direct_share: [f64; 3],
    ) -> Shot {
        let area = self.mesh.patches[shooter.patch as usize].area;
        let mut form_factor_sum = 0.0;
        let (rank, owners) = (self.rank, self.owners);
        let vote = self.vote.get_mut().unwrap_or_else(|e| e.into_inner());
        // Only an emitter's first shot carries direct light: the others
        // leave `direct` alone (adding d * 0 changed no bit, and the loop
        // is bound by its memory traffic).
        let direct = direct_share != [0.0; 3];
        // One rank owns every element: no owner to look up (a read a
        // transfer, at random).
        let all_own = self.ranks == 1;
        let emitted = self.emitted_power;
        let mut landed = (0u64, 0i64);
        for (i, t) in ff.iter().enumerate() {
            if let Some(ahead) = ff.get(i + PREFETCH_AHEAD) {
                let j = ahead.element as usize;
                if !all_own {
                    prefetch(self.element_patch.as_ptr().wrapping_add(j));
                }
                prefetch(self.receiving.as_ptr().wrapping_add(j));
                prefetch(self.radiosity.as_ptr().wrapping_add(j));
                prefetch(self.element_unshot.as_ptr().wrapping_add(j));
                if direct {
                    prefetch(self.direct.as_ptr().wrapping_add(j));
                }
            }

            form_factor_sum += t.form_factor;
            let j = t.element as usize;
            // Other ranks' elements are not set in `receiving`.
            if !all_own && owners.of(self.element_patch[j]) != rank {
                continue;
            }
            let el = self.receiving[j];
            let (l, d) = landing_share(t, area, emitted);
            landed = (landed.0 + l, landed.1 + d);
            Self::touch(vote, rank, owners, el.patch as usize);
            let scale = area / el.area;
            let d = [0, 1, 2].map(|c| el.reflectance[c] * t.radiosity[c] * scale);
            if direct {
                for ((x, d), s) in self.direct[j].iter_mut().zip(d).zip(direct_share) {
                    *x += d * s;
                }
            }
            let patch = el.patch as usize;
            for (c, d) in d.into_iter().enumerate() {
                self.radiosity[j][c] += d;
                self.element_unshot[j][c] += d;
                self.unshot[patch][c] += d * el.patch_share;
            }
        }
        self.shots += 1;
        Shot {
            shooter: shooter.patch,
            power: shooter.power,
            shot_power: power(&region.shoot, area),
            form_factor_sum,
            landed,
        }
    }
}

/// How many transfers ahead [`Solver::land`] asks for the records it will
/// read: a row's transfers reach scattered elements, and each record is a
/// cache miss the loop's few instructions cannot hide.
const PREFETCH_AHEAD: usize = 8;

#[cfg(test)]
mod tests {
    use super::*;

    /// One unit square of 2 x 2 patches that emits 1 W/m^2 and reflects 0.5.
    fn emitting_square() -> LitMesh {
        let mut mesh = crate::mesh::unit_square(2, 1);
        mesh.polygons[0].exitance = [1.0; 3];
        LitMesh::unlit(mesh)
    }

    #[test]
    fn a_patch_of_no_area_under_a_light_keeps_every_display_finite() {
        // Real files carry degenerate triangles (Sponza: patches of no area
        // under its sun). Their share of their patch was 0 / 0, which the
        // carried ambient term then spread over the whole scene.
        let mut mesh = crate::mesh::unit_square(2, 1);
        let n = mesh.elements.len();
        mesh.patches[1].area = 0.0;
        let degenerate = mesh.patches[1].elements.clone();
        for j in degenerate {
            mesh.elements[j as usize].area = 0.0;
        }
        let mut mesh = LitMesh::unlit(mesh);
        mesh.light_field = crate::lights::LightField {
            direct: vec![[1.0; 3]; n],
            sky: vec![[0.0; 3]; n],
            emitted: 1.0,
            delivered: 1.0,
            directional: vec![0.0; n],
        };
        let solver = Solver::new(&mesh);
        for ambient in [AmbientTerm::Off, AmbientTerm::Even, AmbientTerm::Carried] {
            let shown = solver.display_radiosity(ambient);
            assert!(
                shown.iter().flatten().all(|x| x.is_finite()),
                "{ambient:?}: {shown:?}"
            );
        }
    }

    #[test]
    fn the_direct_part_is_what_an_emitters_first_shot_delivers() {
        let mesh = emitting_square();
        let mut solver = Solver::new(&mesh);
        let shoot = |solver: &mut Solver, patch: u32, to: u32| {
            let candidate = solver.local_candidate().expect("a shooter");
            let candidate = Candidate { patch, ..candidate };
            let region = solver.shooting_region(patch);
            let f = 0.1;
            let ff = [Transfer {
                element: to,
                form_factor: f,
                radiosity: region.shoot.map(|s| f * s),
            }];
            solver.shoot_candidate(&candidate, &region, &ff);
        };
        // Patch 0's first shot carries its emission: all of it is direct.
        shoot(&mut solver, 0, 3);
        let direct = solver.direct().expect("known")[3];
        // rho F E A_i / A_j, with equal areas.
        assert!((direct[0] - 0.5 * 0.1 * 1.0).abs() < 1e-12, "{direct:?}");
        // Patch 3's first shot carries its emission (1) and what it received
        // (0.05): only the emission's share of what it delivers is direct.
        shoot(&mut solver, 3, 1);
        let delivered = solver.display_radiosity(AmbientTerm::Off)[1][0] - 1.0;
        assert!((delivered - 0.5 * 0.1 * 1.05).abs() < 1e-12, "{delivered}");
        let direct = solver.direct().expect("known")[1];
        assert!((direct[0] - 0.5 * 0.1 * 1.0).abs() < 1e-12, "{direct:?}");
        // A patch that has shot its emission adds nothing direct again.
        shoot(&mut solver, 0, 2);
        assert_eq!(solver.direct().expect("known")[2], [0.0; 3]);
        // The state keeps it; a state without it (an old checkpoint) leaves
        // it unknown.
        let mut state = solver.state();
        let mut again = Solver::new(&mesh);
        again.restore(&state).expect("same mesh");
        assert_eq!(again.direct(), solver.direct());
        state.direct.clear();
        state.emission_unshot.clear();
        again.restore(&state).expect("same mesh");
        assert_eq!(again.direct(), None);
    }
}

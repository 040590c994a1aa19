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
    /// Fills `out` with (element, F_ij) pairs for shooter patch `shooter`, sorted by element.
    fn form_factors(&mut self, shooter: u32, out: &mut Vec<(u32, f64)>) -> Result<(), Self::Error>;
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

/// Radiosity state over a mesh.
pub struct Solver<'m> {
    mesh: &'m Mesh,
    /// Radiosity B per element, W/m^2 per channel.
    radiosity: Vec<[f64; 3]>,
    /// Unshot radiosity dB per patch.
    unshot: Vec<[f64; 3]>,
    emitted_power: f64,
    shots: u64,
    ff: Vec<(u32, f64)>,
}

fn power(b: &[f64; 3], area: f64) -> f64 {
    (b[0] + b[1] + b[2]) * area
}

impl<'m> Solver<'m> {
    /// Starts with B = dB = E (the emitters' exitance) everywhere.
    pub fn new(mesh: &'m Mesh) -> Self {
        let radiosity = mesh
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
            radiosity,
            unshot,
            emitted_power,
            shots: 0,
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

    /// Unshot power / emitted power.
    pub fn unshot_fraction(&self) -> f64 {
        let unshot: f64 = self
            .unshot
            .iter()
            .zip(&self.mesh.patches)
            .map(|(b, p)| power(b, p.area))
            .sum();
        if self.emitted_power > 0.0 {
            unshot / self.emitted_power
        } else {
            0.0
        }
    }

    /// Whether the stop rule is met.
    pub fn done(&self, rule: &StopRule) -> bool {
        self.shots >= rule.max_shots || self.unshot_fraction() <= rule.threshold
    }

    /// The patch with the largest unshot power (lowest index on ties), if any has some.
    pub fn select_shooter(&self) -> Option<u32> {
        let mut best: Option<(u32, f64)> = None;
        for (i, (b, p)) in self.unshot.iter().zip(&self.mesh.patches).enumerate() {
            let w = power(b, p.area);
            if w > 0.0 && best.is_none_or(|(_, bw)| w > bw) {
                best = Some((i as u32, w));
            }
        }
        best.map(|(i, _)| i)
    }

    /// Distributes the shooter's unshot radiosity through the form factors `ff`.
    pub fn shoot(&mut self, shooter: u32, ff: &[(u32, f64)]) -> Shot {
        let mesh = self.mesh;
        let sp = &mesh.patches[shooter as usize];
        let db = std::mem::take(&mut self.unshot[shooter as usize]);
        let mut form_factor_sum = 0.0;
        for &(j, f) in ff {
            form_factor_sum += f;
            let el = &mesh.elements[j as usize];
            let rho = mesh.polygons[el.polygon as usize].reflectance;
            let scale = f * sp.area / el.area;
            let patch_share = el.area / mesh.patches[el.patch as usize].area;
            for c in 0..3 {
                let d = rho[c] * db[c] * scale;
                self.radiosity[j as usize][c] += d;
                self.unshot[el.patch as usize][c] += d * patch_share;
            }
        }
        self.shots += 1;
        Shot {
            shooter,
            power: power(&db, sp.area),
            form_factor_sum,
        }
    }

    /// One whole shot: select, get form factors, distribute. `None` when nothing is left to shoot.
    pub fn step<S: FormFactorSource>(&mut self, source: &mut S) -> Result<Option<Shot>, S::Error> {
        let Some(shooter) = self.select_shooter() else {
            return Ok(None);
        };
        let mut ff = std::mem::take(&mut self.ff);
        source.form_factors(shooter, &mut ff)?;
        let shot = self.shoot(shooter, &ff);
        self.ff = ff;
        Ok(Some(shot))
    }

    /// The ambient term (Cohen et al. 1988): the unshot radiosity spread
    /// uniformly and multiplied by the interreflection factor 1 / (1 - rho_avg).
    /// For display only; never added to [`Solver::radiosity`].
    pub fn ambient(&self) -> [f64; 3] {
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
            out[c] = unshot / total_area / (1.0 - rho).max(1e-3);
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

//! What a solve shows rather than shoots: the ambient term (for display
//! only: nothing the solver shoots, stores or votes on reads it), radiance
//! B / pi with it, the solution's own direct part, which elements are unlit
//! and how unevenly each patch holds its light (for refinement).

use super::*;

impl<'m> Solver<'m> {
    /// The ambient term (Cohen et al. 1988), for an open scene: the unshot
    /// power U spread uniformly over the area A, of which the fraction f that
    /// shots have been seen to land ([`Solver::retention`]) lands each bounce:
    /// U f / (A (1 - rho_avg f)) per channel (Cohen's 1 / (1 - rho_avg) in a
    /// closed scene). It estimates the light not yet shot; it is kept apart
    /// from [`Solver::radiosity`] and added by [`Solver::display_radiosity`].
    /// Needs the whole solution (one rank, or assembled); ranks use
    /// [`Solver::ambient_from`] with the sum of their [`Solver::local_net_unshot`].
    pub fn ambient(&self) -> [f64; 3] {
        self.ambient_from(self.local_net_unshot())
    }

    /// The ambient term (see [`Solver::ambient`]) for the whole solution's signed
    /// unshot power `net`: the same on every rank, whatever their number.
    pub fn ambient_from(&self, net: NetUnshot) -> [f64; 3] {
        let f = self.retention();
        let total_area = self.total_area;
        if total_area <= 0.0 {
            return [0.0; 3];
        }
        [0, 1, 2].map(|c| {
            let unshot = net[c] as f64 / UNSHOT_ONE * self.emitted_power;
            unshot * f / total_area / (1.0 - self.mean_reflectance[c] * f).max(1e-3)
        })
    }

    /// Radiance for display, W sr^-1 m^-2 per channel: a Lambertian
    /// surface's [`Solver::display_radiosity`] over pi.
    pub fn display_radiance(&self, ambient: AmbientTerm) -> Vec<[f32; 3]> {
        self.display_radiosity(ambient)
            .iter()
            .map(|b| b.map(|x| (x / std::f64::consts::PI) as f32))
            .collect()
    }

    /// Per patch, how unevenly its elements hold their light, W: the sum over
    /// its elements of area times |B - the patch's mean B| (over RGB), the
    /// power that one uniform patch in its place would misplace. Only this
    /// rank's patches are measured (the others are 0).
    pub fn patch_unevenness(&self) -> Vec<f64> {
        let mesh = self.mesh;
        let mut out = vec![0.0; mesh.patches.len()];
        for i in self.own_patches() {
            let p = &mesh.patches[i];
            let mut mean = [0.0; 3];
            for j in p.elements.clone() {
                let (b, a) = (self.radiosity[j as usize], mesh.elements[j as usize].area);
                for c in 0..3 {
                    mean[c] += b[c] * a / p.area;
                }
            }
            out[i] = p
                .elements
                .clone()
                .map(|j| {
                    let b = self.radiosity[j as usize];
                    let a = mesh.elements[j as usize].area;
                    (0..3).map(|c| (b[c] - mean[c]).abs()).sum::<f64>() * a
                })
                .sum();
        }
        out
    }

    /// Per element, whether no light has reached it (it holds no
    /// radiosity of its own: hidden under a box, or above a light panel).
    pub fn unlit(&self) -> Vec<bool> {
        (0..self.radiosity.len() as u32)
            .map(|j| !self.lit(j))
            .collect()
    }

    /// The solution's own direct part per element, W/m^2 per channel: the
    /// light its elements reflect of the emitters' first shots of their
    /// emission (None after resuming a checkpoint that did not keep it).
    pub fn direct(&self) -> Option<&[[f64; 3]]> {
        self.direct_known.then_some(self.direct.as_slice())
    }

    /// Marks the direct part unknown (an assembled solution whose ranks'
    /// direct parts were not gathered).
    pub fn forget_direct(&mut self) {
        self.direct_known = false;
    }

    /// Radiosity for display: B, plus rho times the ambient term `ambient`
    /// asks for (see [`AmbientTerm`]).
    pub fn display_radiosity(&self, ambient: AmbientTerm) -> Vec<[f64; 3]> {
        self.display_radiosities(ambient).collect()
    }

    /// [`Solver::display_radiosity`] element by element, without the
    /// vector (the trace summarises it per node at every point, and in a
    /// big scene a fresh vector per point was tens of megabytes).
    pub fn display_radiosities(&self, ambient: AmbientTerm) -> impl Iterator<Item = [f64; 3]> + '_ {
        // Per element, the irradiance the unshot light will still bring.
        let carried = match ambient {
            AmbientTerm::Carried => self.carried_ambient(),
            _ => None,
        };
        let even = match ambient {
            AmbientTerm::Even => self.ambient(),
            _ => [0.0; 3],
        };
        self.radiosity
            .iter()
            .zip(&self.mesh.elements)
            .map(move |(b, e)| {
                let rho = e.reflectance;
                let amb = match &carried {
                    Some((t, h)) => h[t.group_of(e.patch)],
                    None if takes_ambient(self.mesh, e) => even,
                    None => [0.0; 3],
                };
                [
                    b[0] + rho[0] * amb[0],
                    b[1] + rho[1] * amb[1],
                    b[2] + rho[2] * amb[2],
                ]
            })
    }

    /// The display's ambient term: the irradiance per group of surfaces
    /// that this solver's unshot power will deliver, carried along the
    /// mesh's geometry (`ambient::Transport`), with the transport
    /// (None when nothing is unshot). Needs the whole solution (one rank,
    /// or assembled).
    pub(super) fn carried_ambient(&self) -> Option<(&'m crate::ambient::Transport, Vec<[f64; 3]>)> {
        let mesh = self.mesh;
        if self.own_patches().all(|i| self.unshot[i] == [0.0; 3]) {
            return None;
        }
        let transport = mesh.ambient_transport();
        let mut unshot = vec![[0.0; 3]; transport.groups()];
        for i in self.own_patches().filter(|&i| self.patch_area[i] > 0.0) {
            let g = transport.group_of(i as u32);
            for (u, b) in unshot[g].iter_mut().zip(self.unshot[i]) {
                *u += b * self.patch_area[i];
            }
        }
        Some((transport, transport.irradiance(&unshot)))
    }
}

//! Where the power went: the shots' retention of the ambient term, the
//! energy record (shot, delivered, met back faces) and the balance the
//! report gives.

use super::*;

/// A solver's retention and energy records and which emitters have shot
/// (see [`Solver::retained`]).
pub struct Retained {
    retention: [f64; 2],
    energy: [f64; 3],
    emission_unshot: Vec<bool>,
    direct_known: bool,
}

impl<'m> Solver<'m> {
    /// Records that a shot of `power` (of either sign) landed the fraction
    /// `landed` of it on the scene (the sum of its form factors over all
    /// elements; below 1 where light escapes an open scene). The ambient term
    /// uses the |power|-weighted mean.
    pub fn note_retention(&mut self, power: f64, landed: f64) {
        let power = power.abs();
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

    /// Takes over `other`'s retention and energy records and which
    /// emitters have shot (for a solver assembled from ranks: every rank
    /// holds these whole).
    pub fn copy_retention(&mut self, other: &Solver) {
        self.restore_retained(other.retained());
    }

    /// What [`Solver::copy_retention`] takes over, held apart so that the
    /// solver it comes from can be dropped first.
    pub fn retained(&self) -> Retained {
        Retained {
            retention: self.retention,
            energy: self.energy,
            emission_unshot: self.emission_unshot.clone(),
            direct_known: self.direct_known,
        }
    }

    /// Takes over what [`Solver::retained`] held.
    pub fn restore_retained(&mut self, r: Retained) {
        self.retention = r.retention;
        self.energy = r.energy;
        self.emission_unshot = r.emission_unshot;
        self.direct_known = r.direct_known;
    }

    /// Records that a shot of `shot` W (signed, sum over RGB) delivered
    /// `delivered` W to the elements it reached (sum over ranks) and `back` W
    /// to the black backs of one-sided surfaces: the rest left the scene. In
    /// a closed scene nothing does.
    pub fn note_energy(&mut self, shot: f64, delivered: f64, back: f64) {
        self.energy[0] += shot;
        self.energy[1] += delivered;
        self.energy[2] += back;
    }

    /// Power shot, delivered and absorbed by back faces so far (see
    /// [`Solver::note_energy`]).
    pub fn energy_record(&self) -> [f64; 3] {
        self.energy
    }

    /// Continues an energy record (a checkpoint's).
    pub fn set_energy_record(&mut self, record: [f64; 3]) {
        self.energy = record;
    }

    /// The signed unshot power of this solver's patches, W, sum over RGB
    /// (the whole solution's on one rank or once assembled).
    pub fn net_unshot_power(&self) -> f64 {
        self.own_patches()
            .map(|i| power(&self.unshot[i], self.patch_area[i]))
            .sum()
    }

    /// Where the emitted power has gone so far (the whole solution's, on one
    /// rank or once assembled).
    pub fn energy(&self) -> Energy {
        let emitted = self.emitted_power;
        let unshot = self.net_unshot_power();
        let back_faces = self.energy[2];
        let escaped = self.energy[0] - self.energy[1] - back_faces;
        let absorbed = emitted - unshot - escaped - back_faces;
        Energy {
            emitted,
            absorbed,
            back_faces,
            unshot,
            escaped,
            balance: if emitted > 0.0 {
                (absorbed + back_faces + unshot) / emitted
            } else {
                1.0
            },
        }
    }
}

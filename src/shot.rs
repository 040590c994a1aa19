//! The interface between the solver and whatever finds form factors: what a
//! shooter shoots ([`ShotRegion`]), what lands on one receiving element
//! ([`Transfer`]), and the source that turns one into the other
//! ([`FormFactorSource`]). Both sides import it; it imports neither, so the
//! form-factor maths (`formfactor`) and the GPU sources never reach into the
//! solver, nor the solver into them.

/// Anything that can produce the form factors from a shooter patch to the elements.
pub trait FormFactorSource {
    /// The error a shot can fail with.
    type Error;
    /// Fills `out` with what shooter patch `shooter` sends each element it
    /// reaches, shooting `region` (the solver's `shooting_region`), sorted by element.
    fn form_factors(
        &mut self,
        shooter: u32,
        region: &ShotRegion,
        out: &mut Vec<Transfer>,
    ) -> Result<(), Self::Error>;
}

/// What one shot sends one receiving element.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Transfer {
    /// The receiving element.
    pub element: u32,
    /// F_ij from the shooter patch to the element, as if the patch shot
    /// uniformly (the geometry alone: the share of a shot that lands).
    pub form_factor: f64,
    /// sum_k F_kj * S_k over the shooter's elements k, per channel: the shot
    /// radiosity the element receives before its reflectance and the area
    /// ratio A_i / A_j (F_ij * S_i when the patch shoots uniformly).
    pub radiosity: [f64; 3],
}

/// How a shooter patch shoots: where its hemisphere goes, and what radiosity
/// it and each of its elements shoot.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ShotRegion {
    /// The hemisphere's centre (a point of the patch).
    pub centre: glam::Vec3,
    /// The shooter's unshot power (of |dB|, sum over RGB), W: how much the
    /// shot matters (a weak one may draw a coarser hemisphere).
    pub power: f64,
    /// The radiosity the patch shoots, per channel (area-weighted over its elements).
    pub shoot: [f64; 3],
    /// Per element of the patch (in order), the radiosity it shoots, per
    /// channel: the patch shoots each element's own share, so a coarse
    /// shooter keeps the detail its elements received (hidden elements shoot
    /// nothing). Empty when all equal `shoot` (the patch shoots uniformly).
    pub elements: Vec<[f64; 3]>,
}

impl ShotRegion {
    /// The region of a patch whose elements shoot `elements` (in order; its
    /// area-weighted mean is `shoot`): uniform, with no per-element list,
    /// when every element shoots the same. The one place that decides it.
    pub fn new(centre: glam::Vec3, power: f64, shoot: [f64; 3], elements: Vec<[f64; 3]>) -> Self {
        match elements.first() {
            Some(first) if elements.iter().all(|s| s == first) => Self {
                centre,
                power,
                shoot: *first,
                elements: Vec::new(),
            },
            _ => Self {
                centre,
                power,
                shoot,
                elements,
            },
        }
    }
}

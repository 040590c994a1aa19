//! What a solver is built from: per element what a shot's update reads
//! (`Receiving`), set only for the rank's own elements, and the small rules
//! every part of the solver shares (whether an element takes the ambient
//! term, its share of its patch, a residual's power).

use super::*;

/// An element as a shot's update reads it: a shot of a weak shooter lands
/// on thousands of elements, and reading these from the element and patch
/// records (120 and 80 bytes) was a cache miss apiece, half the update's
/// time in a default render. The same values, so the same bits.
#[derive(Clone, Copy, Debug, bytemuck::Zeroable)]
pub(super) struct Receiving {
    pub(super) reflectance: [f64; 3],
    pub(super) area: f64,
    /// Its share of its patch's area ([`patch_share`]).
    pub(super) patch_share: f64,
    pub(super) patch: u32,
}

/// What a solver keeps of each element, read in one pass over the
/// elements (120-byte records: four passes were most of a solver's set-up,
/// which every rank repeats): this rank's elements' exitance (twice: B and
/// dB) and `Receiving`, every element's patch, and over the elements that
/// take the ambient term their area and area-weighted mean reflectance
/// per channel (summed in element order).
pub(super) struct PerElement {
    pub(super) exitance: Vec<[f64; 3]>,
    pub(super) element_unshot: Vec<[f64; 3]>,
    pub(super) receiving: Vec<Receiving>,
    pub(super) element_patch: Vec<u32>,
    pub(super) mean_reflectance: [f64; 3],
    pub(super) ambient_area: f64,
}

/// Whether element `e` gets the ambient term: every element but those of
/// the back sides of double-sided surfaces (the copies the loader adds: the
/// outside of a double-sided room sees no light, and counting it would
/// spread the unshot light over twice the area).
pub(super) fn takes_ambient(mesh: &Mesh, e: &crate::mesh::Element) -> bool {
    !mesh.polygons[e.polygon as usize].back_side
}

/// Element `e`'s share of its patch's area (0 in a patch of no area: a
/// degenerate triangle of a real file, whose elements have none either).
pub(super) fn patch_share(mesh: &Mesh, e: &crate::mesh::Element) -> f64 {
    let a = mesh.patches[e.patch as usize].area;
    if a > 0.0 {
        e.area / a
    } else {
        0.0
    }
}

/// Power of a radiosity over an area, sum over RGB (signed).
pub(super) fn power(b: &[f64; 3], area: f64) -> f64 {
    (b[0] + b[1] + b[2]) * area
}

/// Power of |b| over an area, sum over RGB: how much a residual still
/// matters, whatever its sign.
pub(super) fn abs_power(b: &[f64; 3], area: f64) -> f64 {
    (b[0].abs() + b[1].abs() + b[2].abs()) * area
}

impl PerElement {
    /// Rank `rank`'s (of `owners`) per-element arrays of `mesh`. The other
    /// ranks' elements stay zero and are never read: their pages, runs of
    /// patches dealt to other ranks, are never touched (the arrays start
    /// as zeroed memory): two ranks of cubes-b1 each took 13-14 ms to set
    /// up, now 9.3-10.3 (the rest reads every element for the sums).
    /// `shot`: whether the emitters' emission has shot already (traced
    /// emitters), so it is not unshot.
    pub(super) fn of(mesh: &Mesh, owners: Owners, rank: usize, shot: bool) -> Self {
        let n = mesh.elements.len();
        let mut exitance = vec![[0.0; 3]; n];
        let mut element_unshot = vec![[0.0; 3]; n];
        let mut receiving: Vec<Receiving> = bytemuck::zeroed_vec(n);
        let mut element_patch = Vec::with_capacity(n);
        // The area starts where `Iterator::sum` starts (its zero's sign),
        // so it is the sum the solver took before, bit for bit.
        let (mut weighted, mut area) = ([0.0; 3], std::iter::empty::<f64>().sum::<f64>());
        for (j, e) in mesh.elements.iter().enumerate() {
            element_patch.push(e.patch);
            if owners.of(e.patch) == rank {
                exitance[j] = mesh.element_exitance(j);
                if !shot {
                    element_unshot[j] = exitance[j];
                }
                receiving[j] = Receiving {
                    reflectance: e.reflectance,
                    area: e.area,
                    patch_share: patch_share(mesh, e),
                    patch: e.patch,
                };
            }
            if takes_ambient(mesh, e) {
                area += e.area;
                for (w, rho) in weighted.iter_mut().zip(e.reflectance) {
                    *w += rho * e.area;
                }
            }
        }
        let mean_reflectance = if area <= 0.0 {
            [0.0; 3]
        } else {
            weighted.map(|x| x / area)
        };
        Self {
            exitance,
            element_unshot,
            receiving,
            element_patch,
            mean_reflectance,
            ambient_area: area,
        }
    }
}

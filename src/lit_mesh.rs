//! A mesh with its lighting state beside it: the geometry (`mesh::Mesh`:
//! polygons, patches, elements, solids) stays plain data that the lights
//! and the ambient term are computed from, and what they compute lives
//! here, so neither the lights nor the ambient transport are part of the
//! geometry they read. Everything that solves or shows a solution takes a
//! [`LitMesh`]; it reads as its [`Mesh`] wherever only geometry is needed.

use crate::ambient::Transport;
use crate::direct::{DirectLight, EmitterField};
use crate::lights::{KeptField, LightField};
use crate::mesh::{Mesh, MeshSettings};
use crate::scene::Scene;
use std::sync::OnceLock;

/// A mesh, what the scene's lights and sky deliver to it, and its ambient
/// transport (built on first use).
#[derive(Clone, Debug, Default)]
pub struct LitMesh {
    /// The geometry.
    pub mesh: Mesh,
    /// What the scene's lights and sky deliver to each element (empty
    /// without them): their one shot, which every solver starts from.
    pub light_field: LightField,
    /// What the emitting polygons deliver to each element, traced (`None`:
    /// they shoot by hemisphere): with the light field, the first shot.
    pub emitter_field: Option<EmitterField>,
    /// Where each group of surfaces' diffuse light lands, for the display's
    /// ambient term (built on first use, see [`LitMesh::ambient_transport`]).
    pub ambient: OnceLock<Transport>,
}

impl std::ops::Deref for LitMesh {
    type Target = Mesh;

    fn deref(&self) -> &Mesh {
        &self.mesh
    }
}

impl LitMesh {
    /// [`Mesh::build`] with the scene's lights.
    pub fn build(scene: &Scene, settings: &MeshSettings) -> Self {
        Self::build_refined(scene, settings, &[])
    }

    /// [`Mesh::build_refined`] with the scene's lights.
    pub fn build_refined(scene: &Scene, settings: &MeshSettings, factors: &[u32]) -> Self {
        Self::build_refined_from(scene, settings, factors, None)
    }

    /// [`LitMesh::build_refined`], reusing the light field `kept` from another
    /// mesh of `scene` for the polygons subdivided alike (the same field, bit
    /// for bit: see `lights::element_field_reusing`).
    pub fn build_refined_from(
        scene: &Scene,
        settings: &MeshSettings,
        factors: &[u32],
        kept: Option<&KeptField>,
    ) -> Self {
        Self::lit(Mesh::build_refined(scene, settings, factors), scene, kept)
    }

    /// `mesh` (a mesh of `scene`) lit by the scene's lights and sky, its
    /// emitters traced ([`DirectLight::emitter_field`]).
    pub fn lit(mesh: Mesh, scene: &Scene, kept: Option<&KeptField>) -> Self {
        let light_field =
            crate::lights::element_field_reusing(&mesh, &scene.lights, scene.background(), kept);
        let emitter_field = DirectLight::emitter_field(scene, &mesh);
        Self {
            mesh,
            light_field,
            emitter_field,
            ambient: OnceLock::new(),
        }
    }

    /// Takes the light field (leaving it empty) to reuse in a finer mesh of
    /// the same scene.
    pub fn take_field(&mut self) -> KeptField {
        KeptField::new(std::mem::take(&mut self.light_field), &self.mesh)
    }

    /// `mesh` with no lights that are not surfaces.
    pub fn unlit(mesh: Mesh) -> Self {
        Self {
            mesh,
            ..Self::default()
        }
    }

    /// The ambient term's transport, estimated on the first call (a few
    /// hundred thousand rays at most): only a display of the solution needs it.
    pub fn ambient_transport(&self) -> &Transport {
        self.ambient.get_or_init(|| Transport::new(&self.mesh))
    }

    /// The power the solution starts from, W (sum over RGB): the surfaces'
    /// emission plus what the lights, the sun and the sky deliver. What the
    /// unshot fraction and a shot's strength are measured against.
    pub fn source_power(&self) -> f64 {
        self.mesh.emitted_power() + self.light_field.emitted
    }
}

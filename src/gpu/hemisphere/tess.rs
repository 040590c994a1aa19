//! The tessellated projection on the device: pieces cut into triangles
//! until every edge's equal-angle image is within the tolerance of its
//! chord, projected by the vertex shader.

use super::*;

/// A vertex of the tessellated projection (see the shader's `TessVertex`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct TessVertex {
    pub(super) p: [f32; 3],
    pub(super) x_override: f32,
    pub(super) x_offset: f32,
    pub(super) piece: u32,
}

/// The tessellated projection's pipeline and per-shot data.
pub(super) struct Tessellation {
    pub(super) pipeline: wgpu::RenderPipeline,
    pub(super) group: wgpu::BindGroup,
    pub(super) pieces_buf: wgpu::Buffer,
    pub(super) vertex_buf: Option<wgpu::Buffer>,
    pub(super) tolerance: f32,
    pub(super) pieces: Vec<PieceGpu>,
    pub(super) vertices: Vec<TessVertex>,
}

impl HemisphereRasterizer {
    /// Switches to the tessellated projection: pieces are cut into triangles
    /// until every edge's equal-angle image is within `tolerance` cells of
    /// its chord, and the vertex shader projects them (see the shader). Builds
    /// its pipeline and buffers once.
    pub fn use_tessellation(
        &mut self,
        device: &wgpu::Device,
        tolerance: f32,
    ) -> Result<(), GpuError> {
        if !(tolerance.is_finite() && tolerance > 0.0) {
            return Err(GpuError::Setting(format!(
                "tessellation tolerance {tolerance} must be a positive number of cells"
            )));
        }
        let pipeline = item_pipeline(
            device,
            &self.device.module,
            ("vs_tess", "fs_tess"),
            wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<TessVertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &wgpu::vertex_attr_array![
                    0 => Float32x3, 1 => Float32, 2 => Float32, 3 => Uint32
                ],
            },
            wgpu::PrimitiveTopology::TriangleList,
        );
        let piece_bytes =
            (self.proxies.corners.len().max(1) * std::mem::size_of::<PieceGpu>()) as u64;
        let pieces = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pieces"),
            size: piece_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let group = item_bind_group(
            device,
            &pipeline,
            &[
                &self.device.uniform,
                &self.device.coverage_buf,
                &self.device.trig,
                &pieces,
            ],
        );
        self.device.tess = Some(Tessellation {
            pipeline,
            group,
            pieces_buf: pieces,
            vertex_buf: None,
            tolerance,
            pieces: Vec::new(),
            vertices: Vec::new(),
        });
        Ok(())
    }

    /// Fills the tessellation's pieces and triangles for every proxy the
    /// shooter can see, in proxy order (so depth ties break alike every run).
    pub(super) fn collect_triangles(&mut self, shooter: &ShooterFrame) {
        let Some(t) = self.device.tess.as_mut() else {
            return;
        };
        t.pieces.clear();
        t.vertices.clear();
        let (outside, corners) = (&self.outside, &self.proxies.corners);
        for (k, poly) in self.proxies.polygons.iter().enumerate() {
            if !in_view(k, poly, outside, shooter) {
                continue;
            }
            let n = shooter.to_local(poly.normal);
            let lookup = poly.quad.map_or_else(Lookup::default, |q| {
                Lookup::new(&self.proxies.quads[q as usize], shooter, n)
            });
            for i in poly.proxies.clone() {
                let d = corners[i as usize].map(|c| shooter.to_local(c - shooter.centre));
                if d.iter().all(|c| c.z <= 0.0) {
                    continue;
                }
                let offset = n.dot(d[0]);
                let piece = t.pieces.len() as u32;
                t.pieces.push(PieceGpu {
                    plane: [n.x, n.y, n.z, offset],
                    item: [
                        self.proxies.element[i as usize],
                        (offset >= 0.0) as u32,
                        0,
                        0,
                    ],
                    origin: lookup.origin,
                    axis: lookup.axis,
                    bilinear: lookup.bilinear,
                    grid: lookup.grid,
                });
                let before = t.vertices.len();
                crate::hemisphere::tessellate(&d, self.res, t.tolerance, |v| {
                    t.vertices.push(TessVertex {
                        p: v.p.to_array(),
                        x_override: v.x_override,
                        x_offset: v.x_offset,
                        piece,
                    })
                });
                if t.vertices.len() == before {
                    t.pieces.pop();
                }
            }
        }
    }
}

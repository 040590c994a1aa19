//! The hemisphere rasteriser: draws every element as seen from a shooter into
//! an R32Uint item buffer of R_phi rows by R_theta columns (see
//! `shaders/hemisphere.wgsl` for the projection and its traps).
//!
//! Per shot the CPU finds a conservative cell rectangle for each piece the
//! shooter can see (`hemisphere::cell_bounds`: cheap, and it culls everything
//! below the tangent plane before any GPU work) and the piece's edge planes in
//! the shooter's frame; the GPU rasterises the rectangles and tests every cell
//! exactly. Pipelines, buffers and geometry are created once.

use super::target::RenderTarget;
use super::GpuError;
use crate::hemisphere::{cell_bounds, Resolution, TileLayout, EMPTY};
use crate::mesh::{Mesh, ShooterFrame};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use std::ops::Range;
use std::time::{Duration, Instant};

/// The WGSL source of the hemisphere pipeline.
pub const SHADER: &str = include_str!("../../shaders/hemisphere.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ShotUniform {
    res: [u32; 4],
    tiles: [u32; 4],
    own: [u32; 4],
    depth: [f32; 4],
}

/// One rectangle to draw, with what the fragment test needs (see the shader's `Rect`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Instance {
    rect: [f32; 4],
    edges: [[f32; 3]; 4],
    plane: [f32; 4],
    item: [u32; 2],
    origin: [f32; 4],
    axis: [f32; 4],
    bilinear: [f32; 4],
    grid: [u32; 4],
}

/// One piece as the tessellated projection's fragment shader reads it (see
/// the shader's `Piece`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PieceGpu {
    plane: [f32; 4],
    item: [u32; 4],
    origin: [f32; 4],
    axis: [f32; 4],
    bilinear: [f32; 4],
    grid: [u32; 4],
}

/// A vertex of the tessellated projection (see the shader's `TessVertex`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TessVertex {
    p: [f32; 3],
    x_override: f32,
    x_offset: f32,
    piece: u32,
}

/// The tessellated projection's pipeline and per-shot data.
struct Tessellation {
    pipeline: wgpu::RenderPipeline,
    group: wgpu::BindGroup,
    pieces_buf: wgpu::Buffer,
    vertex_buf: Option<wgpu::Buffer>,
    tolerance: f32,
    pieces: Vec<PieceGpu>,
    vertices: Vec<TessVertex>,
}

/// Time spent in the phases of one rasterisation.
#[derive(Clone, Copy, Debug, Default)]
pub struct RasterStats {
    /// Finding the cell rectangles on the CPU.
    pub bounds: Duration,
    /// Rectangles drawn (seam copies included), or triangles with the
    /// tessellated projection.
    pub rects: u32,
    /// Uploading, drawing and waiting for the GPU.
    pub rasterise: Duration,
    /// Mapping the item buffer and copying it out.
    pub readback: Duration,
}

/// A polygon's pieces and what culling needs.
struct PolygonProxies {
    proxies: Range<u32>,
    normal: Vec3,
    centre: Vec3,
    radius: f32,
    /// Its bilinear element grid, when it is drawn in pieces (an index into `quads`).
    quad: Option<u32>,
    /// The solid it bounds, if any (an index into `Mesh::solids`).
    solid: Option<u32>,
}

/// A quad polygon drawn in pieces: its corners (world space) and element
/// grid (elements along u and v, elements per patch along u and v), from
/// which the fragment shader finds the element at a hit point.
struct QuadGrid {
    corners: [Vec3; 4],
    grid: [u32; 4],
}

/// The outline of a quad polygon (its patches' outer corners), or `None` for
/// a triangle.
fn polygon_outline(mesh: &Mesh, poly: &crate::mesh::MeshPolygon) -> Option<[Vec3; 4]> {
    let patches = &mesh.patches[poly.patches.start as usize..poly.patches.end as usize];
    let first = patches.first()?;
    if first.corners[3] == first.corners[2] {
        return None;
    }
    let [pu, pv] = poly.patch_grid;
    let at = |i: u32, j: u32| &patches[(j * pu + i) as usize];
    Some([
        at(0, 0).corners[0],
        at(pu - 1, 0).corners[1],
        at(pu - 1, pv - 1).corners[2],
        at(0, pv - 1).corners[3],
    ])
}

/// What the fragment shader needs to find the element of a piece of a quad
/// polygon at a hit point, in the shooter's frame: the polygon's bilinear map
/// p = o + u e1 + v e2 + u v g written in a 2-D basis of its plane (x along e1).
#[derive(Clone, Copy, Default)]
struct Lookup {
    /// o (shooter frame), and g's y coordinate.
    origin: [f32; 4],
    /// The plane's x axis (shooter frame).
    axis: [f32; 4],
    /// |e1|, e2.x, e2.y, g.x.
    bilinear: [f32; 4],
    /// Elements along u, along v, per patch along u, per patch along v (all 0: a single element).
    grid: [u32; 4],
}

impl Lookup {
    fn new(q: &QuadGrid, shooter: &ShooterFrame, n: Vec3) -> Self {
        let c = q.corners.map(|p| shooter.to_local(p - shooter.centre));
        let (e1, e2, g) = (c[1] - c[0], c[3] - c[0], c[0] - c[1] + c[2] - c[3]);
        let x = e1.normalize_or_zero();
        let y = n.cross(x);
        Self {
            origin: [c[0].x, c[0].y, c[0].z, g.dot(y)],
            axis: [x.x, x.y, x.z, 0.0],
            bilinear: [e1.length(), e2.dot(x), e2.dot(y), g.dot(x)],
            grid: q.grid,
        }
    }
}

/// Pipelines, buffers and scene geometry for hemisphere rendering, created once.
pub struct HemisphereRasterizer {
    res: Resolution,
    far: f32,
    /// Corners of every rasterisation proxy (world space).
    corners: Vec<[Vec3; 4]>,
    /// Element each proxy belongs to (the polygon's first element for a piece of a quad grid).
    element: Vec<u32>,
    /// Quad polygons drawn in pieces.
    quads: Vec<QuadGrid>,
    polygons: Vec<PolygonProxies>,
    /// The mesh's closed solids, and per shot whether the shooter is outside
    /// each (then its back faces are not drawn: see `Mesh::solids`).
    solids: Vec<crate::mesh::Solid>,
    outside: Vec<bool>,
    cull_solids: bool,
    /// Rectangles of the current shot, CPU side (reused).
    instances: Vec<Instance>,
    instance_buf: wgpu::Buffer,
    uniform: wgpu::Buffer,
    pipeline: wgpu::RenderPipeline,
    group: wgpu::BindGroup,
    target: RenderTarget,
    /// Per-element count of the cells each element covers, occluded or not
    /// (hybrid form factors' visibility denominator), and its readback copy.
    coverage_buf: wgpu::Buffer,
    coverage_read: wgpu::Buffer,
    /// Cell directions (f64 table), shared by both projections.
    trig: wgpu::Buffer,
    /// The compiled shader, shared by both projections' pipelines.
    module: wgpu::ShaderModule,
    /// The tessellated projection, when chosen (see [`HemisphereRasterizer::use_tessellation`]).
    tess: Option<Tessellation>,
    /// Whether to count coverage this shot.
    count_coverage: bool,
    /// The last shot's coverage per element (empty unless counting).
    coverage: Vec<u32>,
    elements: usize,
}

impl HemisphereRasterizer {
    /// Builds the pipeline and the per-shot buffers for `mesh`. `pieces`
    /// says what is drawn: with N >= 1 every quad polygon is drawn as at most
    /// N x N pieces (never more than its element grid) and the fragment
    /// shader finds the element from the hit point's (u, v), so a shot costs
    /// what the visible geometry costs; with 0 every element is drawn on its
    /// own. Triangles are always drawn per element. Results are the same
    /// either way. `extent` bounds every distance in the scene.
    pub fn new(
        device: &wgpu::Device,
        mesh: &Mesh,
        res: Resolution,
        pieces: u32,
        extent: f32,
    ) -> Result<Self, GpuError> {
        let limits = device.limits();
        if res.cols > limits.max_texture_dimension_2d || res.rows > limits.max_texture_dimension_2d
        {
            return Err(GpuError::TooLarge(format!(
                "hemisphere {res} exceeds the texture limit {}",
                limits.max_texture_dimension_2d
            )));
        }
        let mut corners = Vec::new();
        let mut element = Vec::new();
        let mut quads = Vec::new();
        let mut polygons = Vec::with_capacity(mesh.polygons.len());
        for (k, poly) in mesh.polygons.iter().enumerate() {
            let first = corners.len() as u32;
            let (mut lo, mut hi) = (Vec3::MAX, Vec3::MIN);
            for id in poly.elements.clone() {
                for p in mesh.elements[id as usize].corners {
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
            let outline = polygon_outline(mesh, poly);
            let quad = match outline {
                Some(c) if pieces > 0 => {
                    let (nu, nv) = (
                        poly.patch_grid[0] * poly.element_grid[0],
                        poly.patch_grid[1] * poly.element_grid[1],
                    );
                    let (su, sv) = (pieces.min(nu), pieces.min(nv));
                    let at = |u: f32, v: f32| crate::mesh::bilinear(&c, u, v);
                    for j in 0..sv {
                        for i in 0..su {
                            let (u0, u1) = (i as f32 / su as f32, (i + 1) as f32 / su as f32);
                            let (v0, v1) = (j as f32 / sv as f32, (j + 1) as f32 / sv as f32);
                            corners.push([at(u0, v0), at(u1, v0), at(u1, v1), at(u0, v1)]);
                            element.push(poly.elements.start);
                        }
                    }
                    quads.push(QuadGrid {
                        corners: c,
                        grid: [nu, nv, poly.element_grid[0], poly.element_grid[1]],
                    });
                    Some(quads.len() as u32 - 1)
                }
                _ => {
                    for id in poly.elements.clone() {
                        corners.push(mesh.elements[id as usize].corners);
                        element.push(id);
                    }
                    None
                }
            };
            polygons.push(PolygonProxies {
                proxies: first..corners.len() as u32,
                normal: poly.normal,
                centre: 0.5 * (lo + hi),
                radius: 0.5 * (hi - lo).length(),
                quad,
                solid: mesh.solid_of.get(k).copied().flatten(),
            });
        }
        let max_instances = 2 * corners.len().max(1) as u64;
        let instance_bytes = max_instances * std::mem::size_of::<Instance>() as u64;
        if instance_bytes > limits.max_buffer_size {
            return Err(GpuError::TooLarge(format!(
                "{} rasterisation proxies need {instance_bytes} bytes of rectangles",
                corners.len()
            )));
        }
        let instance_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("rectangles"),
            size: instance_bytes,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shot"),
            size: std::mem::size_of::<ShotUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        // One u32 per element (at least one, as a binding may not be empty).
        let coverage_bytes = 4 * mesh.elements.len().max(1) as u64;
        if coverage_bytes > limits.max_storage_buffer_binding_size {
            return Err(GpuError::TooLarge(format!(
                "{} elements need {coverage_bytes} bytes of coverage counters",
                mesh.elements.len()
            )));
        }
        let coverage_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("coverage"),
            size: coverage_bytes,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let coverage_read = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("coverage readback"),
            size: coverage_bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        // Cell directions from f64, the same on every driver.
        let table = crate::hemisphere::direction_table(res);
        let trig = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("cell directions"),
            size: std::mem::size_of_val(table.as_slice()) as u64,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: true,
        });
        trig.slice(..)
            .get_mapped_range_mut()
            .map_err(|e| GpuError::Failed(e.to_string()))?
            .copy_from_slice(bytemuck::cast_slice(&table));
        trig.unmap();
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("hemisphere.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let pipeline = item_pipeline(
            device,
            &module,
            ("vs", "fs"),
            wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<Instance>() as u64,
                step_mode: wgpu::VertexStepMode::Instance,
                attributes: &wgpu::vertex_attr_array![
                    0 => Float32x4, 1 => Float32x3, 2 => Float32x3, 3 => Float32x3,
                    4 => Float32x3, 5 => Float32x4, 6 => Uint32x2, 7 => Float32x4,
                    8 => Float32x4, 9 => Float32x4, 10 => Uint32x4
                ],
            },
            wgpu::PrimitiveTopology::TriangleStrip,
        );
        let group = item_bind_group(device, &pipeline, &[&uniform, &coverage_buf, &trig]);
        let target = RenderTarget::new(
            device,
            res.cols,
            res.rows,
            wgpu::TextureFormat::R32Uint,
            4,
            "item buffer",
        );
        Ok(Self {
            res,
            far: extent.max(1e-6) * 2.0,
            instances: Vec::with_capacity(corners.len()),
            corners,
            element,
            quads,
            polygons,
            solids: mesh.solids.clone(),
            outside: Vec::new(),
            cull_solids: true,
            instance_buf,
            uniform,
            pipeline,
            group,
            target,
            coverage_buf,
            coverage_read,
            trig,
            module,
            tess: None,
            count_coverage: false,
            coverage: Vec::new(),
            elements: mesh.elements.len(),
        })
    }

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
            &self.module,
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
        let piece_bytes = (self.corners.len().max(1) * std::mem::size_of::<PieceGpu>()) as u64;
        let pieces = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pieces"),
            size: piece_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let group = item_bind_group(
            device,
            &pipeline,
            &[&self.uniform, &self.coverage_buf, &self.trig, &pieces],
        );
        self.tess = Some(Tessellation {
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
    fn collect_triangles(&mut self, shooter: &ShooterFrame) {
        let Some(t) = self.tess.as_mut() else {
            return;
        };
        t.pieces.clear();
        t.vertices.clear();
        let (outside, corners) = (&self.outside, &self.corners);
        for (k, poly) in self.polygons.iter().enumerate() {
            if !in_view(k, poly, corners, outside, shooter) {
                continue;
            }
            let n = shooter.to_local(poly.normal);
            let lookup = poly.quad.map_or_else(Lookup::default, |q| {
                Lookup::new(&self.quads[q as usize], shooter, n)
            });
            for i in poly.proxies.clone() {
                let d = self.corners[i as usize].map(|c| shooter.to_local(c - shooter.centre));
                if d.iter().all(|c| c.z <= 0.0) {
                    continue;
                }
                let offset = n.dot(d[0]);
                let piece = t.pieces.len() as u32;
                t.pieces.push(PieceGpu {
                    plane: [n.x, n.y, n.z, offset],
                    item: [self.element[i as usize], (offset >= 0.0) as u32, 0, 0],
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

    /// Whether shots skip the back faces of closed solids they are outside
    /// of (on by default; the item buffer is the same either way, cell for
    /// cell, but for rays grazing a silhouette edge).
    pub fn set_cull_solids(&mut self, on: bool) {
        self.cull_solids = on;
    }

    /// Which solids `shooter` is outside of (their back faces need no drawing).
    fn find_outside(&mut self, shooter: &ShooterFrame) {
        let cull = self.cull_solids;
        self.outside.clear();
        self.outside
            .extend(self.solids.iter().map(|s| cull && !s.holds(shooter.centre)));
    }

    /// Whether each shot also counts, per element, every cell whose ray hits
    /// the element whether or not something nearer hides it (see [`HemisphereRasterizer::coverage_pairs`]).
    pub fn set_count_coverage(&mut self, on: bool) {
        self.count_coverage = on;
        if !on {
            self.coverage.clear();
        }
    }

    /// The last shot's unoccluded cell counts (this rank's cells only), as
    /// (element, count) for every element with some; none unless
    /// [`HemisphereRasterizer::set_count_coverage`] is on.
    pub fn coverage_pairs(&self) -> impl Iterator<Item = (u32, u64)> + '_ {
        self.coverage
            .iter()
            .enumerate()
            .filter(|(_, &c)| c > 0)
            .map(|(id, &c)| (id as u32, c as u64))
    }

    /// The hemisphere resolution.
    pub fn resolution(&self) -> Resolution {
        self.res
    }

    /// Fills `self.instances` with a rectangle for every proxy the shooter can
    /// see, in proxy order (so the draw order, and with it every depth tie, is
    /// the same on every run), seam copies right after their originals. Large
    /// scenes split the polygons between threads and join the lists in order.
    fn collect_rects(&mut self, shooter: &ShooterFrame, ownership: Option<Ownership>) {
        self.instances.clear();
        let threads = if self.corners.len() < PARALLEL_PROXIES {
            1
        } else {
            std::thread::available_parallelism()
                .map_or(1, |n| n.get())
                .min(8)
        };
        let (res, far, corners, element, quads, outside) = (
            self.res,
            self.far,
            &self.corners,
            &self.element,
            &self.quads,
            &self.outside,
        );
        let visit = |polys: &[PolygonProxies], first: usize, out: &mut Vec<Instance>| {
            for (k, poly) in polys.iter().enumerate() {
                if !in_view(first + k, poly, corners, outside, shooter) {
                    continue;
                }
                let n = shooter.to_local(poly.normal);
                let lookup = poly.quad.map_or_else(Lookup::default, |q| {
                    Lookup::new(&quads[q as usize], shooter, n)
                });
                for i in poly.proxies.clone() {
                    let d = corners[i as usize].map(|c| shooter.to_local(c - shooter.centre));
                    push_piece(
                        out,
                        &d,
                        n,
                        element[i as usize],
                        &lookup,
                        res,
                        far,
                        ownership,
                    );
                }
            }
        };
        if threads <= 1 {
            visit(&self.polygons, 0, &mut self.instances);
            return;
        }
        // Contiguous runs of polygons with about equal proxy counts.
        let per = self.corners.len().div_ceil(threads) as u32;
        let mut bounds = vec![0usize];
        for (k, poly) in self.polygons.iter().enumerate() {
            if poly.proxies.end >= per * bounds.len() as u32 && bounds.len() < threads {
                bounds.push(k + 1);
            }
        }
        bounds.push(self.polygons.len());
        bounds.dedup();
        let polygons = &self.polygons;
        let parts: Vec<Vec<Instance>> = std::thread::scope(|scope| {
            let handles: Vec<_> = bounds
                .windows(2)
                .map(|w| {
                    let (lo, hi) = (w[0], w[1]);
                    scope.spawn(move || {
                        let mut out = Vec::new();
                        visit(&polygons[lo..hi], lo, &mut out);
                        out
                    })
                })
                .collect();
            // A panic in a worker is a bug; surface it on this thread.
            handles
                .into_iter()
                .map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
                .collect()
        });
        for part in parts {
            self.instances.extend_from_slice(&part);
        }
    }

    /// Renders the cells of the tiles that rank `own` of `layout` owns, as seen
    /// from `shooter`, into `items` (row-major, R_phi x R_theta). Cells other
    /// ranks own are [`EMPTY`].
    pub fn render(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        shooter: &ShooterFrame,
        layout: &TileLayout,
        own: (u32, u32),
        items: &mut Vec<u32>,
    ) -> Result<RasterStats, GpuError> {
        let start = Instant::now();
        // With 1 x 1 tiles over several ranks, draw only this rank's cells,
        // packed (see the shader); otherwise draw all and discard others' cells.
        // The tessellated projection always draws the full image: packing
        // would move its vertices relative to the rasteriser's sub-pixel
        // grid, and rank counts would no longer agree bit for bit.
        let lattice =
            layout.tile_w == 1 && layout.tile_h == 1 && layout.ranks() > 1 && self.tess.is_none();
        // Over several ranks, skip rectangles that hold none of this rank's cells.
        let ownership = (layout.ranks() > 1).then_some(Ownership {
            tile: [layout.tile_w as f32, layout.tile_h as f32],
            grid: [layout.px as f32, layout.py as f32],
            own: [own.0 as f32, own.1 as f32],
            cells: [self.res.cols as f32, self.res.rows as f32],
        });
        self.find_outside(shooter);
        if self.tess.is_some() {
            self.collect_triangles(shooter);
        } else {
            self.collect_rects(shooter, ownership);
        }
        let bounds = start.elapsed();
        let u = ShotUniform {
            res: [self.res.rows, self.res.cols, 0, 0],
            tiles: [
                layout.tile_w.max(1),
                layout.tile_h.max(1),
                layout.px.max(1),
                layout.py.max(1),
            ],
            own: [own.0, own.1, lattice as u32, self.count_coverage as u32],
            depth: [1.0 / self.far, 0.0, 0.0, 0.0],
        };
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&u));
        if let Some(t) = self.tess.as_mut() {
            if !t.vertices.is_empty() {
                let bytes: &[u8] = bytemuck::cast_slice(&t.vertices);
                // Grows to the largest shot, then is reused.
                if t.vertex_buf
                    .as_ref()
                    .is_none_or(|b| b.size() < bytes.len() as u64)
                {
                    t.vertex_buf = Some(device.create_buffer(&wgpu::BufferDescriptor {
                        label: Some("tessellated vertices"),
                        size: (bytes.len() as u64).next_power_of_two(),
                        usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
                        mapped_at_creation: false,
                    }));
                }
                if let Some(b) = &t.vertex_buf {
                    queue.write_buffer(b, 0, bytes);
                }
                queue.write_buffer(&t.pieces_buf, 0, bytemuck::cast_slice(&t.pieces));
            }
        } else {
            let bytes: &[u8] = bytemuck::cast_slice(&self.instances);
            if !bytes.is_empty() {
                queue.write_buffer(&self.instance_buf, 0, bytes);
            }
        }
        let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("shot"),
        });
        if self.count_coverage {
            enc.clear_buffer(&self.coverage_buf, 0, None);
        }
        {
            let mut pass = self.target.begin_pass(
                &mut enc,
                wgpu::Color {
                    r: EMPTY as f64,
                    g: 0.0,
                    b: 0.0,
                    a: 0.0,
                },
            );
            match &self.tess {
                Some(t) => {
                    if let (Some(b), false) = (&t.vertex_buf, t.vertices.is_empty()) {
                        pass.set_pipeline(&t.pipeline);
                        pass.set_bind_group(0, &t.group, &[]);
                        pass.set_vertex_buffer(0, b.slice(..));
                        pass.draw(0..t.vertices.len() as u32, 0..1);
                    }
                }
                None if !self.instances.is_empty() => {
                    pass.set_pipeline(&self.pipeline);
                    pass.set_bind_group(0, &self.group, &[]);
                    pass.set_vertex_buffer(0, self.instance_buf.slice(..));
                    pass.draw(0..4, 0..self.instances.len() as u32);
                }
                None => {}
            }
        }
        self.target.copy_out(&mut enc);
        if self.count_coverage {
            enc.copy_buffer_to_buffer(&self.coverage_buf, 0, &self.coverage_read, 0, None);
        }
        let submission = queue.submit([enc.finish()]);
        items.clear();
        let mut waited = None;
        let word = |b: &[u8]| u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        if lattice {
            // Unpack this rank's cells to their places; the rest stay EMPTY.
            items.resize(self.res.cells(), EMPTY);
            let (cols, rows) = (self.res.cols as usize, self.res.rows as usize);
            let (px, py, x0, y0) = (
                layout.px as usize,
                layout.py as usize,
                own.0 as usize,
                own.1 as usize,
            );
            self.target
                .read_rows(device, submission.clone(), |r, row| {
                    waited.get_or_insert_with(Instant::now);
                    let p = r * py + y0;
                    if p < rows {
                        for (c, b) in row
                            .chunks_exact(4)
                            .enumerate()
                            .take_while(|(c, _)| c * px + x0 < cols)
                        {
                            items[p * cols + c * px + x0] = word(b);
                        }
                    }
                })?;
        } else {
            items.reserve(self.res.cells());
            self.target
                .read_rows(device, submission.clone(), |_, row| {
                    waited.get_or_insert_with(Instant::now);
                    items.extend(row.chunks_exact(4).map(word));
                })?;
        }
        if self.count_coverage {
            // The item buffer's wait covered this submission; this map is immediate.
            super::map_read(device, &self.coverage_read, submission)?;
            {
                let view = self
                    .coverage_read
                    .slice(..)
                    .get_mapped_range()
                    .map_err(|e| GpuError::Failed(e.to_string()))?;
                self.coverage.clear();
                self.coverage.extend(
                    view.chunks_exact(4)
                        .take(self.elements)
                        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                );
            }
            self.coverage_read.unmap();
        }
        let read_start = waited.unwrap_or_else(Instant::now);
        let rasterise = read_start - start - bounds;
        Ok(RasterStats {
            bounds,
            rects: match &self.tess {
                Some(t) => (t.vertices.len() / 3) as u32,
                None => self.instances.len() as u32,
            },
            rasterise,
            readback: read_start.elapsed(),
        })
    }
}

/// Whether polygon `k` (`poly`) can show in the shooter's hemisphere: the
/// shooter never sees its own polygon, polygons wholly below its plane, or
/// the hidden back faces of solids it is outside of. The one cull both
/// projections use.
fn in_view(
    k: usize,
    poly: &PolygonProxies,
    corners: &[[Vec3; 4]],
    outside: &[bool],
    shooter: &ShooterFrame,
) -> bool {
    k as u32 != shooter.polygon
        && (poly.centre - shooter.centre).dot(shooter.normal) + poly.radius > 0.0
        && !hidden_back_face(poly, corners, outside, shooter)
}

/// Whether `poly` is a back face of a solid that the shooter is outside of
/// (`outside`, per solid): then a front face of the same solid is nearer in
/// every direction it covers, and it need not be drawn.
fn hidden_back_face(
    poly: &PolygonProxies,
    corners: &[[Vec3; 4]],
    outside: &[bool],
    shooter: &ShooterFrame,
) -> bool {
    poly.solid
        .is_some_and(|s| outside.get(s as usize).copied().unwrap_or(false))
        && corners
            .get(poly.proxies.start as usize)
            .is_some_and(|c| (shooter.centre - c[0]).dot(poly.normal) < 0.0)
}

/// Scenes with at least this many proxies find their rectangles on several threads.
const PARALLEL_PROXIES: usize = 8192;

/// Adds the rectangle(s) of one planar quad `d` (corners in the shooter's frame)
/// of element `element` on a plane with normal `n`; with an `ownership`, only
/// rectangles that hold a cell of one of this rank's tiles.
/// The tiles one rank of a grid owns: tile (p, t) of `tile_w` x `tile_h`
/// cells with t mod px = ox and p mod py = oy.
#[derive(Clone, Copy)]
struct Ownership {
    tile: [f32; 2],
    grid: [f32; 2],
    own: [f32; 2],
    cells: [f32; 2],
}

impl Ownership {
    /// Whether the cell rectangle holds the centre of a cell of one of this rank's tiles.
    fn holds_own(&self, x0: f32, x1: f32, y0: f32, y1: f32) -> bool {
        let any = |lo: f32, hi: f32, axis: usize| {
            // Cells whose centres are inside, then the tiles holding them.
            let (c0, c1) = (
                (lo - 0.5).ceil().max(0.0),
                (hi - 0.5).floor().min(self.cells[axis] - 1.0),
            );
            let (t0, t1) = (
                (c0 / self.tile[axis]).floor(),
                (c1 / self.tile[axis]).floor(),
            );
            c0 <= c1
                && ((t0 - self.own[axis]) / self.grid[axis]).ceil()
                    <= ((t1 - self.own[axis]) / self.grid[axis]).floor()
        };
        any(x0, x1, 0) && any(y0, y1, 1)
    }
}

#[allow(clippy::too_many_arguments)]
fn push_piece(
    out: &mut Vec<Instance>,
    d: &[Vec3; 4],
    n: Vec3,
    element: u32,
    lookup: &Lookup,
    res: Resolution,
    far: f32,
    ownership: Option<Ownership>,
) {
    let Some(r) = cell_bounds(d, res, far) else {
        return;
    };
    let cols = res.cols as f32;
    let mine = |x0: f32, x1: f32| ownership.is_none_or(|o| o.holds_own(x0, x1, r.y0, r.y1));
    let (primary, wrapped) = (
        mine(r.x0, r.x1),
        r.x1 > cols && mine(r.x0 - cols, r.x1 - cols),
    );
    if !primary && !wrapped {
        return;
    }
    // The shooter is in front when it is on the side n points to.
    let offset = n.dot(d[0]);
    let back = offset >= 0.0;
    // Inside <=> the direction is on the inner side of every edge plane; which
    // side is inner depends on the side the shooter sees.
    let sign = if back { 1.0 } else { -1.0 };
    let edges =
        std::array::from_fn(|k| (d[k].cross(d[(k + 1) % 4]).normalize_or_zero() * sign).to_array());
    let inst = Instance {
        rect: [r.x0, r.x1, r.y0, r.y1],
        edges,
        plane: [n.x, n.y, n.z, offset],
        item: [element, back as u32],
        origin: lookup.origin,
        axis: lookup.axis,
        bilinear: lookup.bilinear,
        grid: lookup.grid,
    };
    if primary {
        out.push(inst);
    }
    if wrapped {
        out.push(Instance {
            rect: [r.x0 - cols, r.x1 - cols, r.y0, r.y1],
            ..inst
        });
    }
}

/// A pipeline that draws element ids into the R32Uint item buffer with a
/// depth test (both projections: the entry points and vertex layout differ).
fn item_pipeline(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    (vs, fs): (&str, &str),
    vertices: wgpu::VertexBufferLayout,
    topology: wgpu::PrimitiveTopology,
) -> wgpu::RenderPipeline {
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(vs),
        layout: None,
        vertex: wgpu::VertexState {
            module,
            entry_point: Some(vs),
            compilation_options: Default::default(),
            buffers: &[Some(vertices)],
        },
        primitive: wgpu::PrimitiveState {
            topology,
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: wgpu::TextureFormat::Depth32Float,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module,
            entry_point: Some(fs),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format: wgpu::TextureFormat::R32Uint,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// Group 0 of `pipeline`: `buffers` at bindings 0, 1, 2, ... in order.
fn item_bind_group(
    device: &wgpu::Device,
    pipeline: &wgpu::RenderPipeline,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("hemisphere"),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

//! Renders the solved mesh from a camera into a linear-radiance image.

use super::target::RenderTarget;
use super::GpuError;
use crate::mesh::Mesh;
use crate::scene::Camera;
use bytemuck::{Pod, Zeroable};
use glam::Mat4;

/// The WGSL source of the view pipeline.
pub const SHADER: &str = include_str!("../../shaders/view.wgsl");

/// How element radiosities become pixel colours.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Shading {
    /// Interpolated from the elements around each vertex (within a polygon).
    Smooth,
    /// One value per element.
    Flat,
}

/// Image size and shading.
#[derive(Clone, Copy, Debug)]
pub struct ViewSettings {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Smooth or flat.
    pub shading: Shading,
    /// Samples per pixel along each axis (box-filtered).
    pub supersample: u32,
    /// Draw every element's edges in black on top.
    pub wireframe: bool,
}

/// Vertices in one draw of the view at most (whole triangles).
const DRAW_VERTICES: u32 = 3 << 16;
/// Vertices in one upload of the view's vertex buffer at most: each is
/// staged and handed to the device before the next is made.
const UPLOAD_VERTICES: usize = 1 << 19;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Vertex {
    pos: [f32; 3],
    radiance: [f32; 3],
}

/// Vertices of the view's triangles per element: two triangles for a
/// quadrilateral, one for a triangle.
fn vertex_count(mesh: &Mesh) -> usize {
    mesh.elements
        .iter()
        .map(|e| if e.vertices[3] != e.vertices[2] { 6 } else { 3 })
        .sum()
}

/// The view's triangles, element by element, handed to `emit` in chunks
/// of at most [`UPLOAD_VERTICES`] (whole triangles), so the whole list is
/// never held at once (Sponza's is 250 MB).
fn vertex_chunks(shown: &Shown<'_>, shading: Shading, mut emit: impl FnMut(&[Vertex])) {
    let Shown {
        mesh,
        radiance,
        hidden,
    } = *shown;
    let smooth: Vec<[f32; 3]> = if shading == Shading::Smooth {
        crate::interpolate::vertex_values(mesh, radiance, hidden)
    } else {
        Vec::new()
    };
    let mut out = Vec::with_capacity(UPLOAD_VERTICES.min(6 * mesh.elements.len()));
    for (e, r) in mesh.elements.iter().zip(radiance) {
        let corner = |k: usize| Vertex {
            pos: e.corners[k].to_array(),
            radiance: if shading == Shading::Smooth {
                smooth[e.vertices[k] as usize]
            } else {
                *r
            },
        };
        out.extend([corner(0), corner(1), corner(2)]);
        if e.vertices[3] != e.vertices[2] {
            out.extend([corner(0), corner(2), corner(3)]);
        }
        if out.len() + 6 > UPLOAD_VERTICES {
            emit(&out);
            out.clear();
        }
    }
    if !out.is_empty() {
        emit(&out);
    }
}

/// Renders `mesh` with per-element `radiance` (W sr^-1 m^-2) from `camera`.
/// Returns `width * height` RGB pixels, top row first. (Builds a
/// [`ViewRenderer`] for one image; keep one to draw many.)
pub fn render_view(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    mesh: &Mesh,
    radiance: &[[f32; 3]],
    camera: &Camera,
    settings: &ViewSettings,
) -> Result<Vec<[f32; 3]>, GpuError> {
    ViewRenderer::new(device).render(device, queue, mesh, radiance, camera, settings)
}

/// The near and far planes the view uses for `mesh` seen from `camera`
/// (ray casts that must see what the rasteriser sees use the same).
pub fn view_depth_range(mesh: &Mesh, camera: &Camera) -> (f32, f32) {
    let far = mesh
        .vertices
        .iter()
        .map(|v| (*v - camera.position).length())
        .fold(1e-3f32, f32::max)
        * 1.5;
    (camera.znear.max(far * 1e-5), far)
}

/// A buffer that grows as needed and is otherwise reused.
struct Grown {
    buffer: Option<wgpu::Buffer>,
    usage: wgpu::BufferUsages,
    label: &'static str,
}

impl Grown {
    fn new(usage: wgpu::BufferUsages, label: &'static str) -> Self {
        Self {
            buffer: None,
            usage: usage | wgpu::BufferUsages::COPY_DST,
            label,
        }
    }

    fn write(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        bytes: &[u8],
    ) -> Option<wgpu::Buffer> {
        let buffer = self.reserve(device, bytes.len() as u64);
        if !bytes.is_empty() {
            queue.write_buffer(&buffer, 0, bytes);
        }
        Some(buffer)
    }

    /// The buffer, grown to hold at least `bytes`.
    fn reserve(&mut self, device: &wgpu::Device, bytes: u64) -> wgpu::Buffer {
        let size = bytes.max(16).next_multiple_of(4);
        match &self.buffer {
            Some(b) if b.size() >= size => b.clone(),
            _ => {
                let b = device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(self.label),
                    size: size.next_power_of_two(),
                    usage: self.usage,
                    mapped_at_creation: false,
                });
                self.buffer = Some(b.clone());
                b
            }
        }
    }
}

/// The camera view's pipelines, uniform, vertex buffers and target, made
/// once and reused for every image (the viewer draws one per change).
pub struct ViewRenderer {
    back_pipeline: wgpu::RenderPipeline,
    pipeline: wgpu::RenderPipeline,
    wire_pipeline: wgpu::RenderPipeline,
    uniform: wgpu::Buffer,
    group: wgpu::BindGroup,
    back_group: wgpu::BindGroup,
    wire_group: wgpu::BindGroup,
    vertices: Grown,
    lines: Grown,
    target: Option<((u32, u32), RenderTarget)>,
}

impl ViewRenderer {
    /// Builds the pipelines on `device`.
    pub fn new(device: &wgpu::Device) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("view.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let make_pipeline = |topology, vs: &str, fs: &str, cull_mode| {
            view_pipeline(device, &module, topology, [vs, fs], cull_mode)
        };
        let triangles = wgpu::PrimitiveTopology::TriangleList;
        // Back faces first, a hair farther; then front faces (see view.wgsl).
        let back_pipeline = make_pipeline(triangles, "vs_back", "fs", Some(wgpu::Face::Front));
        let pipeline = make_pipeline(triangles, "vs", "fs", Some(wgpu::Face::Back));
        // Element edges, pulled a hair towards the camera in the shader so they win the depth test.
        let wire_pipeline = make_pipeline(
            wgpu::PrimitiveTopology::LineList,
            "vs_line",
            "fs_line",
            None,
        );
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("camera"),
            size: 64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let group_for = |p: &wgpu::RenderPipeline| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("view"),
                layout: &p.get_bind_group_layout(0),
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniform.as_entire_binding(),
                }],
            })
        };
        let (group, wire_group) = (group_for(&pipeline), group_for(&wire_pipeline));
        let back_group = group_for(&back_pipeline);
        Self {
            back_pipeline,
            pipeline,
            wire_pipeline,
            uniform,
            group,
            back_group,
            wire_group,
            vertices: Grown::new(wgpu::BufferUsages::VERTEX, "view vertices"),
            lines: Grown::new(wgpu::BufferUsages::VERTEX, "wireframe"),
            target: None,
        }
    }

    /// Renders `mesh` with per-element `radiance` (W sr^-1 m^-2) from
    /// `camera`: `width * height` RGB pixels, top row first.
    pub fn render(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        mesh: &Mesh,
        radiance: &[[f32; 3]],
        camera: &Camera,
        settings: &ViewSettings,
    ) -> Result<Vec<[f32; 3]>, GpuError> {
        let shown = Shown {
            mesh,
            radiance,
            hidden: None,
        };
        self.render_masked(device, queue, shown, camera, settings)
    }

    /// Uploads `shown`'s triangles chunk by chunk (see [`vertex_chunks`]):
    /// the vertex buffer and how many vertices it holds.
    fn upload(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        shown: &Shown<'_>,
        shading: Shading,
    ) -> (wgpu::Buffer, u32) {
        let count = vertex_count(shown.mesh);
        let buffer = self
            .vertices
            .reserve(device, (count * std::mem::size_of::<Vertex>()) as u64);
        let mut offset = 0;
        vertex_chunks(shown, shading, |chunk| {
            let bytes: &[u8] = bytemuck::cast_slice(chunk);
            queue.write_buffer(&buffer, offset, bytes);
            offset += bytes.len() as u64;
            // Hands the staged copy to the device now: the staging of
            // the chunks need not all be held until the draw's submission.
            queue.submit([]);
        });
        (buffer, count as u32)
    }

    /// [`ViewRenderer::render`] of what `shown` says, where smooth shading
    /// leaves the elements marked hidden (no light reached them) out of
    /// their vertices' values ([`crate::interpolate::vertex_values`]).
    pub fn render_masked(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        shown: Shown<'_>,
        camera: &Camera,
        settings: &ViewSettings,
    ) -> Result<Vec<[f32; 3]>, GpuError> {
        let mesh = shown.mesh;
        let ss = settings.supersample.max(1);
        let (w, h) = (settings.width * ss, settings.height * ss);
        let max_dim = device.limits().max_texture_dimension_2d;
        if w > max_dim || h > max_dim || w == 0 || h == 0 {
            return Err(GpuError::TooLarge(format!(
                "image {w}x{h} (limit {max_dim})"
            )));
        }
        let (near, far) = view_depth_range(mesh, camera);
        let aspect = settings.width as f32 / settings.height as f32;
        let view = Mat4::from_rotation_translation(camera.rotation, camera.position).inverse();
        let view_proj = Mat4::perspective_rh(camera.yfov, aspect, near, far) * view;
        queue.write_buffer(
            &self.uniform,
            0,
            bytemuck::cast_slice(&view_proj.to_cols_array()),
        );
        let (vbuf, vertex_count) = self.upload(device, queue, &shown, settings.shading);
        let lines = if settings.wireframe {
            wire_lines(mesh)
        } else {
            Vec::new()
        };
        let lbuf = if lines.is_empty() {
            None
        } else {
            self.lines
                .write(device, queue, bytemuck::cast_slice(&lines))
        };
        if self.target.as_ref().is_none_or(|(size, _)| *size != (w, h)) {
            self.target = Some((
                (w, h),
                RenderTarget::new(device, w, h, wgpu::TextureFormat::Rgba32Float, 16, "view"),
            ));
        }
        let Some((_, target)) = &self.target else {
            return Err(GpuError::Failed("no view target".into()));
        };
        let mut enc = device.create_command_encoder(&Default::default());
        {
            let mut pass = target.begin_pass(&mut enc, wgpu::Color::BLACK);
            pass.set_vertex_buffer(0, vbuf.slice(..));
            for (pipeline, group) in [
                (&self.back_pipeline, &self.back_group),
                (&self.pipeline, &self.group),
            ] {
                pass.set_pipeline(pipeline);
                pass.set_bind_group(0, group, &[]);
                // In draws of a bounded size, as the hemisphere's: lavapipe
                // keeps the vertices of its largest draw, and Sponza's 10
                // million in one draw took hundreds of megabytes. Draws keep
                // their order, so the picture is the same.
                for first in (0..vertex_count).step_by(DRAW_VERTICES as usize) {
                    pass.draw(first..(first + DRAW_VERTICES).min(vertex_count), 0..1);
                }
            }
            if let Some(buffer) = &lbuf {
                pass.set_pipeline(&self.wire_pipeline);
                pass.set_bind_group(0, &self.wire_group, &[]);
                pass.set_vertex_buffer(0, buffer.slice(..));
                pass.draw(0..lines.len() as u32, 0..1);
            }
        }
        target.copy_out(&mut enc);
        let submission = queue.submit([enc.finish()]);
        read_image(device, target, submission, settings)
    }
}

/// One of the view's pipelines: `topology` drawn by the entry points
/// `[vertex, fragment]` of `module`, culling `cull_mode`, into an RGBA f32
/// target with a depth test.
fn view_pipeline(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    topology: wgpu::PrimitiveTopology,
    [vs, fs]: [&str; 2],
    cull_mode: Option<wgpu::Face>,
) -> wgpu::RenderPipeline {
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("view"),
        layout: None,
        vertex: wgpu::VertexState {
            module,
            entry_point: Some(vs),
            compilation_options: Default::default(),
            buffers: &[Some(wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<Vertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3],
            })],
        },
        primitive: wgpu::PrimitiveState {
            topology,
            front_face: wgpu::FrontFace::Ccw,
            cull_mode,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: wgpu::TextureFormat::Depth32Float,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::LessEqual),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module,
            entry_point: Some(fs),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format: wgpu::TextureFormat::Rgba32Float,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// What a view shows: the mesh, each element's radiance, and the elements
/// no light reached (left out of smooth shading's vertex values).
#[derive(Clone, Copy)]
pub struct Shown<'a> {
    /// The mesh.
    pub mesh: &'a Mesh,
    /// Per element, its radiance.
    pub radiance: &'a [[f32; 3]],
    /// Per element, whether no light reached it.
    pub hidden: Option<&'a [bool]>,
}

/// The elements' edges as line segments (the wireframe).
fn wire_lines(mesh: &Mesh) -> Vec<Vertex> {
    mesh.elements
        .iter()
        .flat_map(|e| {
            let n = if e.vertices[3] == e.vertices[2] { 3 } else { 4 };
            (0..n).flat_map(move |k| [e.corners[k], e.corners[(k + 1) % n]])
        })
        .map(|p| Vertex {
            pos: p.to_array(),
            radiance: [0.0; 3],
        })
        .collect()
}

/// The drawn target read back and box-filtered down to the image's size.
fn read_image(
    device: &wgpu::Device,
    target: &RenderTarget,
    submission: wgpu::SubmissionIndex,
    settings: &ViewSettings,
) -> Result<Vec<[f32; 3]>, GpuError> {
    let ss = settings.supersample.max(1);
    let mut out = vec![[0.0f32; 3]; (settings.width * settings.height) as usize];
    let norm = 1.0 / (ss * ss) as f32;
    target.read_rows(device, submission, |y, row| {
        for (x, px) in row.chunks_exact(16).enumerate() {
            let o = &mut out[(y as u32 / ss * settings.width + x as u32 / ss) as usize];
            for c in 0..3 {
                let b = &px[c * 4..c * 4 + 4];
                o[c] += f32::from_le_bytes([b[0], b[1], b[2], b[3]]) * norm;
            }
        }
    })?;
    Ok(out)
}

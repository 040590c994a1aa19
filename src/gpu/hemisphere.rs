//! The hemisphere rasteriser: draws every element as seen from a shooter into
//! an R32Uint item buffer of R_phi rows by R_theta columns (see
//! `shaders/hemisphere.wgsl` for the projection and its traps).

use super::{map_read, GpuError};
use crate::hemisphere::{Resolution, TileLayout, EMPTY};
use crate::mesh::{Mesh, ShooterFrame};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use std::time::{Duration, Instant};

/// The WGSL source of the hemisphere pipelines.
pub const SHADER: &str = include_str!("../../shaders/hemisphere.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ShotUniform {
    centre: [f32; 4],
    tangent: [f32; 4],
    bitangent: [f32; 4],
    normal: [f32; 4],
    res: [u32; 4],
    tiles: [u32; 4],
    own: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ProxyGpu {
    c: [[f32; 4]; 4],
    n: [f32; 3],
    polygon: u32,
    element: u32,
    _pad: [u32; 3],
}

/// Time spent in the phases of one rasterisation.
#[derive(Clone, Copy, Debug, Default)]
pub struct RasterStats {
    /// Recording and submitting the GPU work and waiting for it.
    pub rasterise: Duration,
    /// Mapping the item buffer and copying it out.
    pub readback: Duration,
}

/// Pipelines, buffers and scene geometry for hemisphere rendering, created once.
pub struct HemisphereRasterizer {
    res: Resolution,
    far: f32,
    proxy_count: u32,
    uniform: wgpu::Buffer,
    bounds_pipeline: wgpu::ComputePipeline,
    draw_pipeline: wgpu::RenderPipeline,
    bounds_group: wgpu::BindGroup,
    draw_group: wgpu::BindGroup,
    color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    color: wgpu::Texture,
    readback: wgpu::Buffer,
    padded_row: u32,
}

fn split_proxies(mesh: &Mesh, split: u32) -> Vec<ProxyGpu> {
    let split = split.max(1);
    let mut out = Vec::with_capacity(mesh.elements.len() * (split * split) as usize);
    for (id, e) in mesh.elements.iter().enumerate() {
        let n = mesh.polygons[e.polygon as usize].normal;
        let c = e.corners;
        let at = |u: f32, v: f32| -> Vec3 {
            c[0] * (1.0 - u) * (1.0 - v)
                + c[1] * u * (1.0 - v)
                + c[2] * u * v
                + c[3] * (1.0 - u) * v
        };
        for j in 0..split {
            for i in 0..split {
                let (u0, u1) = (i as f32 / split as f32, (i + 1) as f32 / split as f32);
                let (v0, v1) = (j as f32 / split as f32, (j + 1) as f32 / split as f32);
                let q = if split == 1 {
                    c
                } else {
                    [at(u0, v0), at(u1, v0), at(u1, v1), at(u0, v1)]
                };
                out.push(ProxyGpu {
                    c: q.map(|p| [p.x, p.y, p.z, 1.0]),
                    n: n.to_array(),
                    polygon: e.polygon,
                    element: id as u32,
                    _pad: [0; 3],
                });
            }
        }
    }
    out
}

impl HemisphereRasterizer {
    /// Uploads the mesh and builds the pipelines. `split` cuts each element into
    /// split x split proxies for tighter rasterisation bounds (results are exact
    /// either way). `extent` bounds every distance in the scene (the depth range).
    pub fn new(
        device: &wgpu::Device,
        mesh: &Mesh,
        res: Resolution,
        split: u32,
        extent: f32,
    ) -> Result<Self, GpuError> {
        let proxies = split_proxies(mesh, split);
        let limits = device.limits();
        let bytes = (proxies.len() * std::mem::size_of::<ProxyGpu>()) as u64;
        if bytes > limits.max_storage_buffer_binding_size as u64
            || proxies.len() as u64 * 12 > u32::MAX as u64
        {
            return Err(GpuError::TooLarge(format!(
                "{} rasterisation proxies ({bytes} bytes)",
                proxies.len()
            )));
        }
        if res.cols > limits.max_texture_dimension_2d || res.rows > limits.max_texture_dimension_2d
        {
            return Err(GpuError::TooLarge(format!(
                "hemisphere {res} exceeds the texture limit {}",
                limits.max_texture_dimension_2d
            )));
        }
        use wgpu::util::DeviceExt;
        let proxy_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("proxies"),
            // An empty scene still needs a bindable buffer.
            contents: if proxies.is_empty() {
                &[0u8; std::mem::size_of::<ProxyGpu>()]
            } else {
                bytemuck::cast_slice(&proxies)
            },
            usage: wgpu::BufferUsages::STORAGE,
        });
        let rects = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("rects"),
            size: (proxies.len().max(1) * 16) as u64,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shot"),
            size: std::mem::size_of::<ShotUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("hemisphere.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let bounds_pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("bounds"),
            layout: None,
            module: &module,
            entry_point: Some("bounds"),
            compilation_options: Default::default(),
            cache: None,
        });
        let draw_pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("hemisphere"),
            layout: None,
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
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
                module: &module,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: wgpu::TextureFormat::R32Uint,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let bounds_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("bounds"),
            layout: &bounds_pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: proxy_buf.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: rects.as_entire_binding(),
                },
            ],
        });
        let draw_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("draw"),
            layout: &draw_pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: proxy_buf.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: rects.as_entire_binding(),
                },
            ],
        });
        let size = wgpu::Extent3d {
            width: res.cols,
            height: res.rows,
            depth_or_array_layers: 1,
        };
        let color = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("item buffer"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R32Uint,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let depth = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("hemisphere depth"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Depth32Float,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        });
        let padded_row = (res.cols * 4).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
            * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("item readback"),
            size: padded_row as u64 * res.rows as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Self {
            res,
            far: extent.max(1e-6) * 2.0,
            proxy_count: proxies.len() as u32,
            uniform,
            bounds_pipeline,
            draw_pipeline,
            bounds_group,
            draw_group,
            color_view: color.create_view(&Default::default()),
            depth_view: depth.create_view(&Default::default()),
            color,
            readback,
            padded_row,
        })
    }

    /// The hemisphere resolution.
    pub fn resolution(&self) -> Resolution {
        self.res
    }

    /// Number of rasterisation proxies drawn per shot.
    pub fn proxy_count(&self) -> u32 {
        self.proxy_count
    }

    /// Renders the cells of the tiles that rank `own` of `layout` owns, as seen
    /// from `shooter`, into `items` (row-major, R_phi x R_theta). Cells other
    /// ranks own are [`EMPTY`].
    pub fn render(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        shooter: &ShooterFrame,
        layout: &TileLayout,
        own: (u32, u32),
        items: &mut Vec<u32>,
    ) -> Result<RasterStats, GpuError> {
        let start = Instant::now();
        let v4 = |v: Vec3, w: f32| [v.x, v.y, v.z, w];
        let u = ShotUniform {
            centre: v4(shooter.centre, self.far),
            tangent: v4(shooter.tangent, 0.0),
            bitangent: v4(shooter.bitangent, 0.0),
            normal: v4(shooter.normal, 0.0),
            res: [
                self.res.rows,
                self.res.cols,
                shooter.polygon,
                self.proxy_count,
            ],
            tiles: [
                layout.tile_w.max(1),
                layout.tile_h.max(1),
                layout.px.max(1),
                layout.py.max(1),
            ],
            own: [own.0, own.1, 0, 0],
        };
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&u));
        let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("shot"),
        });
        if self.proxy_count > 0 {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("bounds"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.bounds_pipeline);
            pass.set_bind_group(0, &self.bounds_group, &[]);
            let groups = self.proxy_count.div_ceil(64);
            pass.dispatch_workgroups(groups.min(65535), groups.div_ceil(65535), 1);
        }
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("hemisphere"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &self.color_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color {
                            r: EMPTY as f64,
                            g: 0.0,
                            b: 0.0,
                            a: 0.0,
                        }),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if self.proxy_count > 0 {
                pass.set_pipeline(&self.draw_pipeline);
                pass.set_bind_group(0, &self.draw_group, &[]);
                pass.draw(0..self.proxy_count * 12, 0..1);
            }
        }
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &self.color,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &self.readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(self.padded_row),
                    rows_per_image: Some(self.res.rows),
                },
            },
            wgpu::Extent3d {
                width: self.res.cols,
                height: self.res.rows,
                depth_or_array_layers: 1,
            },
        );
        let submission = queue.submit([enc.finish()]);
        map_read(device, &self.readback, submission)?;
        let rasterise = start.elapsed();
        let start = Instant::now();
        {
            let view = self
                .readback
                .slice(..)
                .get_mapped_range()
                .map_err(|e| GpuError::Failed(e.to_string()))?;
            items.clear();
            items.reserve(self.res.cells());
            let row_bytes = self.res.cols as usize * 4;
            for row in view.chunks_exact(self.padded_row as usize) {
                items.extend(
                    row[..row_bytes]
                        .chunks_exact(4)
                        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                );
            }
        }
        self.readback.unmap();
        Ok(RasterStats {
            rasterise,
            readback: start.elapsed(),
        })
    }
}

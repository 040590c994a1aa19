//! The rasteriser's device objects: buffers, the cell-direction table and
//! the pipelines and bind groups of both projections, made once.

use super::*;
use crate::raster::{CellShot, DrawCells, DrawTimes};

/// A buffer of `size` bytes for `usage`, not mapped.
pub(super) fn buffer(
    device: &wgpu::Device,
    label: &str,
    size: u64,
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage,
        mapped_at_creation: false,
    })
}

/// The cell directions from f64 (`hemisphere::direction_table`), the same
/// on every driver, as the shader's uniform table: entry k holds row k's
/// (sin phi, cos phi) and column k's (cos theta, sin theta).
pub(super) fn direction_buffer(
    device: &wgpu::Device,
    res: Resolution,
) -> Result<wgpu::Buffer, GpuError> {
    let table = crate::hemisphere::direction_table(res);
    let (rows, cols) = table.split_at(res.rows as usize);
    let most = crate::hemisphere::MAX_COUNT as usize;
    if rows.len() > most || cols.len() > most {
        return Err(GpuError::TooLarge(format!(
            "hemisphere {res}: the shader's direction table holds at most {most} rows and columns"
        )));
    }
    let mut entries = vec![[0.0f32; 4]; most];
    for (k, e) in entries.iter_mut().enumerate() {
        if let Some(r) = rows.get(k) {
            e[..2].copy_from_slice(r);
        }
        if let Some(c) = cols.get(k) {
            e[2..].copy_from_slice(c);
        }
    }
    let trig = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("cell directions"),
        size: std::mem::size_of_val(entries.as_slice()) as u64,
        usage: wgpu::BufferUsages::UNIFORM,
        mapped_at_creation: true,
    });
    trig.slice(..)
        .get_mapped_range_mut()
        .map_err(|e| GpuError::Failed(e.to_string()))?
        .copy_from_slice(bytemuck::cast_slice(&entries));
    trig.unmap();
    Ok(trig)
}

/// The exact projection's pipeline: one instanced rectangle per piece.
pub(super) fn rect_pipeline(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
) -> wgpu::RenderPipeline {
    item_pipeline(
        device,
        module,
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
    )
}

/// A pipeline that draws element ids into the R32Uint item buffer with a
/// depth test (both projections: the entry points and vertex layout differ).
pub(super) fn item_pipeline(
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
pub(super) fn item_bind_group(
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

/// The rectangle buffer's most bytes (two rectangles a proxy) and the
/// coverage counters' bytes (one u32 an element, at least one, as a
/// binding may not be empty), or why the device cannot hold them or a
/// hemisphere of `res`.
pub(super) fn sizes(
    limits: &wgpu::Limits,
    res: Resolution,
    proxies: usize,
    elements: usize,
) -> Result<[u64; 2], GpuError> {
    let most = limits.max_texture_dimension_2d;
    if res.cols > most || res.rows > most {
        return Err(GpuError::TooLarge(format!(
            "hemisphere {res} exceeds the texture limit {most}"
        )));
    }
    let max_instances = 2 * proxies.max(1) as u64;
    let instance_bytes = max_instances * std::mem::size_of::<Instance>() as u64;
    if instance_bytes > limits.max_buffer_size {
        return Err(GpuError::TooLarge(format!(
            "{proxies} rasterisation proxies need {instance_bytes} bytes of rectangles"
        )));
    }
    let coverage_bytes = 4 * elements.max(1) as u64;
    if coverage_bytes > limits.max_storage_buffer_binding_size {
        return Err(GpuError::TooLarge(format!(
            "{elements} elements need {coverage_bytes} bytes of coverage counters"
        )));
    }
    Ok([instance_bytes, coverage_bytes])
}

/// The rasteriser's device objects: the rectangles' buffer, the shot's
/// uniform, the pipelines, the item buffer and the coverage counters, and
/// the tessellated projection when chosen. It draws a shot's cells on the
/// device ([`DrawCells`]).
pub(super) struct DeviceCells {
    pub(super) res: Resolution,
    pub(super) elements: usize,
    pub(super) instance_buf: wgpu::Buffer,
    pub(super) uniform: wgpu::Buffer,
    pub(super) pipeline: wgpu::RenderPipeline,
    pub(super) group: wgpu::BindGroup,
    pub(super) target: RenderTarget,
    /// Per-element count of the cells each element covers, occluded or not
    /// (hybrid form factors' visibility denominator), and its readback copy.
    pub(super) coverage_buf: wgpu::Buffer,
    pub(super) coverage_read: wgpu::Buffer,
    /// Cell directions (f64 table), shared by both projections.
    pub(super) trig: wgpu::Buffer,
    /// The compiled shader, shared by both projections' pipelines.
    pub(super) module: wgpu::ShaderModule,
    /// The tessellated projection, when chosen.
    pub(super) tess: Option<Tessellation>,
}

impl DrawCells for DeviceCells {
    type Context<'c> = (&'c wgpu::Device, &'c wgpu::Queue);
    type Error = GpuError;

    fn draw(
        &mut self,
        gpu: Self::Context<'_>,
        shot: &CellShot<'_>,
        items: &mut Vec<u32>,
        coverage: &mut Vec<(u32, u64)>,
    ) -> Result<DrawTimes, GpuError> {
        let start = Instant::now();
        self.upload(gpu, shot)?;
        let submission = self.submit(gpu, shot);
        let waited = self.read_items(gpu.0, submission.clone(), shot, items)?;
        if shot.coverage {
            self.read_coverage(gpu.0, submission, coverage)?;
        }
        let read_start = waited.unwrap_or_else(Instant::now);
        Ok(DrawTimes {
            rasterise: read_start - start,
            readback: read_start.elapsed(),
            packed: false,
        })
    }
}

impl DeviceCells {
    /// Writes the shot's uniform and the rectangles (or triangles) it draws.
    fn upload(
        &mut self,
        (device, queue): (&wgpu::Device, &wgpu::Queue),
        shot: &CellShot<'_>,
    ) -> Result<(), GpuError> {
        let CellShot {
            layout,
            own,
            lattice,
            ..
        } = *shot;
        let tiles = [
            layout.tile_w.max(1),
            layout.tile_h.max(1),
            layout.px.max(1),
            layout.py.max(1),
        ];
        let u = ShotUniform {
            res: [self.res.rows, self.res.cols, 0, 0],
            tiles,
            own: [own.0, own.1, lattice as u32, shot.coverage as u32],
            depth: [1.0 / shot.far, 0.0, 0.0, 0.0],
            per_tile: tiles.map(|d| 1.0 / d as f32),
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
            let bytes: &[u8] = bytemuck::cast_slice(shot.instances);
            let need = bytes.len() as u64;
            if need > self.instance_buf.size() {
                // Rectangles cut to a rank's tiles can outnumber the proxies
                // twice over: grow to the largest shot, then reuse.
                let most = device.limits().max_buffer_size;
                if need > most {
                    return Err(GpuError::TooLarge(format!(
                        "{} rectangles need {need} bytes, over the device's {most}",
                        shot.instances.len()
                    )));
                }
                log::debug!(
                    "rectangle buffer grows to {} rectangles ({:.0} MB)",
                    shot.instances.len(),
                    need.next_power_of_two().min(most) as f64 / 1e6
                );
                self.instance_buf = buffer(
                    device,
                    "rectangles",
                    need.next_power_of_two().min(most),
                    wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
                );
            }
            if !bytes.is_empty() {
                queue.write_buffer(&self.instance_buf, 0, bytes);
            }
        }
        Ok(())
    }

    /// Records and submits the drawing and the copies out.
    fn submit(
        &self,
        (device, queue): (&wgpu::Device, &wgpu::Queue),
        shot: &CellShot<'_>,
    ) -> wgpu::SubmissionIndex {
        let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("shot"),
        });
        if shot.coverage {
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
                None if !shot.instances.is_empty() => {
                    pass.set_pipeline(&self.pipeline);
                    pass.set_bind_group(0, &self.group, &[]);
                    pass.set_vertex_buffer(0, self.instance_buf.slice(..));
                    // In draws of a bounded size: lavapipe keeps every
                    // vertex of a draw, and one of Sponza's 385 000
                    // rectangles took 0.5 GB that it kept for good. Draws
                    // keep their order, so the item buffer is the same.
                    let n = shot.instances.len() as u32;
                    for first in (0..n).step_by(DRAW_INSTANCES as usize) {
                        pass.draw(0..4, first..(first + DRAW_INSTANCES).min(n));
                    }
                }
                None => {}
            }
        }
        self.target.copy_out_part(&mut enc, self.drawn_part(shot));
        if shot.coverage {
            enc.copy_buffer_to_buffer(&self.coverage_buf, 0, &self.coverage_read, 0, None);
        }
        queue.submit([enc.finish()])
    }

    /// The part of the item buffer a shot drew into (columns, rows): a
    /// rank's packed lattice cells fill only the top-left of it, one cell
    /// of every `px` x `py`; otherwise all of it.
    fn drawn_part(&self, shot: &CellShot<'_>) -> [u32; 2] {
        let (cols, rows) = (self.res.cols, self.res.rows);
        if !shot.lattice {
            return [cols, rows];
        }
        let (layout, (x0, y0)) = (shot.layout, shot.own);
        [
            (cols - x0.min(cols)).div_ceil(layout.px.max(1)),
            (rows - y0.min(rows)).div_ceil(layout.py.max(1)),
        ]
    }

    /// Reads this rank's cells of the item buffer into `items` (a packed
    /// lattice unpacked to its places); returns when the wait ended.
    fn read_items(
        &self,
        device: &wgpu::Device,
        submission: wgpu::SubmissionIndex,
        shot: &CellShot<'_>,
        items: &mut Vec<u32>,
    ) -> Result<Option<Instant>, GpuError> {
        let CellShot {
            layout,
            own,
            lattice,
            ..
        } = *shot;
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
                .read_rows_part(device, submission, self.drawn_part(shot), |r, row| {
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
            self.target.read_rows(device, submission, |_, row| {
                waited.get_or_insert_with(Instant::now);
                items.extend(row.chunks_exact(4).map(word));
            })?;
        }
        Ok(waited)
    }

    /// Reads the coverage counts into `coverage` (the shot counted them).
    fn read_coverage(
        &self,
        device: &wgpu::Device,
        submission: wgpu::SubmissionIndex,
        coverage: &mut Vec<(u32, u64)>,
    ) -> Result<(), GpuError> {
        {
            // The item buffer's wait covered this submission; this map is immediate.
            super::super::map_read(
                device,
                &self.coverage_read,
                submission,
                ..self.coverage_read.size(),
            )?;
            {
                let view = self
                    .coverage_read
                    .slice(..)
                    .get_mapped_range()
                    .map_err(|e| GpuError::Failed(e.to_string()))?;
                // Straight from the mapped counts to the pairs: most
                // elements are not in view, and a block of zeros is skipped
                // with one test (every rank reads every element's count).
                coverage.clear();
                let bytes = &view[..4 * self.elements.min(view.len() / 4)];
                // Mapped ranges are aligned (wgpu::MAP_ALIGNMENT); copy if not.
                let copied: Vec<u32>;
                let counts: &[u32] = match bytemuck::try_cast_slice(bytes) {
                    Ok(counts) => counts,
                    Err(_) => {
                        copied = bytes
                            .chunks_exact(4)
                            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                            .collect();
                        &copied
                    }
                };
                for (b, block) in counts.chunks(COVERAGE_BLOCK).enumerate() {
                    if block.iter().fold(0, |a, &c| a | c) == 0 {
                        continue;
                    }
                    let first = b * COVERAGE_BLOCK;
                    coverage.extend(
                        block
                            .iter()
                            .enumerate()
                            .filter(|(_, &c)| c > 0)
                            .map(|(k, &c)| ((first + k) as u32, u64::from(c))),
                    );
                }
            }
            self.coverage_read.unmap();
        }
        Ok(())
    }
}

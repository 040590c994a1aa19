//! The rasteriser's device objects: buffers, the cell-direction table and
//! the pipelines and bind groups of both projections, made once.

use super::*;

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

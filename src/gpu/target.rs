//! An offscreen colour + depth target that is read back to the CPU: what both
//! the hemisphere rasteriser and the camera view draw into.

use super::{map_read, GpuError};

/// Colour and depth textures of one size, and a buffer to read the colour back.
pub(crate) struct RenderTarget {
    color: wgpu::Texture,
    color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    readback: wgpu::Buffer,
    size: wgpu::Extent3d,
    row_bytes: u32,
    padded_row: u32,
}

impl RenderTarget {
    /// A `width` x `height` target of `format` (`bytes_per_pixel` each) with a Depth32Float buffer.
    pub(crate) fn new(
        device: &wgpu::Device,
        width: u32,
        height: u32,
        format: wgpu::TextureFormat,
        bytes_per_pixel: u32,
        label: &str,
    ) -> Self {
        let size = wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        };
        let texture = |format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let color = texture(
            format,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        );
        let depth = texture(
            wgpu::TextureFormat::Depth32Float,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        // Copies to buffers need rows padded to 256 bytes.
        let row_bytes = width * bytes_per_pixel;
        let padded_row = row_bytes.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
            * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: padded_row as u64 * height as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Self {
            color_view: color.create_view(&Default::default()),
            depth_view: depth.create_view(&Default::default()),
            color,
            readback,
            size,
            row_bytes,
            padded_row,
        }
    }

    /// Begins a pass that clears colour to `clear` and depth to 1 (depth compare Less).
    pub(crate) fn begin_pass<'e>(
        &self,
        enc: &'e mut wgpu::CommandEncoder,
        clear: wgpu::Color,
    ) -> wgpu::RenderPass<'e> {
        enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: None,
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &self.color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(clear),
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
        })
    }

    /// Records the copy of the colour texture into the readback buffer.
    pub(crate) fn copy_out(&self, enc: &mut wgpu::CommandEncoder) {
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
                    rows_per_image: Some(self.size.height),
                },
            },
            self.size,
        );
    }

    /// Waits (bounded) for `submission`, then hands every row's bytes, top
    /// first and without padding, to `row`.
    pub(crate) fn read_rows(
        &self,
        device: &wgpu::Device,
        submission: wgpu::SubmissionIndex,
        mut row: impl FnMut(usize, &[u8]),
    ) -> Result<(), GpuError> {
        map_read(device, &self.readback, submission)?;
        {
            let view = self
                .readback
                .slice(..)
                .get_mapped_range()
                .map_err(|e| GpuError::Failed(e.to_string()))?;
            for (y, padded) in view.chunks_exact(self.padded_row as usize).enumerate() {
                row(y, &padded[..self.row_bytes as usize]);
            }
        }
        self.readback.unmap();
        Ok(())
    }
}

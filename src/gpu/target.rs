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
        self.copy_out_part(enc, [self.size.width, self.size.height]);
    }

    /// Records the copy of the texture's top-left `part` (width, height)
    /// into the readback buffer, rows padded to the part's width: what a
    /// shot that drew only there needs (a rank's packed lattice cells).
    pub(crate) fn copy_out_part(&self, enc: &mut wgpu::CommandEncoder, part: [u32; 2]) {
        let [width, height] = self.clamped(part);
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
                    bytes_per_row: Some(self.padded(width)),
                    rows_per_image: Some(height),
                },
            },
            wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
        );
    }

    /// Waits (bounded) for `submission`, then hands every row's bytes, top
    /// first and without padding, to `row`.
    pub(crate) fn read_rows(
        &self,
        device: &wgpu::Device,
        submission: wgpu::SubmissionIndex,
        row: impl FnMut(usize, &[u8]),
    ) -> Result<(), GpuError> {
        let whole = [self.size.width, self.size.height];
        self.read_rows_part(device, submission, whole, row)
    }

    /// [`RenderTarget::read_rows`] of what [`RenderTarget::copy_out_part`]
    /// copied of `part`: only its bytes are mapped and read.
    pub(crate) fn read_rows_part(
        &self,
        device: &wgpu::Device,
        submission: wgpu::SubmissionIndex,
        part: [u32; 2],
        mut row: impl FnMut(usize, &[u8]),
    ) -> Result<(), GpuError> {
        let [width, height] = self.clamped(part);
        let padded = u64::from(self.padded(width));
        let bytes = padded * u64::from(height);
        let row_bytes = (self.row_bytes / self.size.width.max(1) * width) as usize;
        map_read(device, &self.readback, submission, ..bytes)?;
        {
            let view = self
                .readback
                .slice(..bytes)
                .get_mapped_range()
                .map_err(|e| GpuError::Failed(e.to_string()))?;
            for (y, padded) in view.chunks_exact(padded as usize).enumerate() {
                row(y, &padded[..row_bytes]);
            }
        }
        self.readback.unmap();
        Ok(())
    }

    /// `part` within the texture, at least one texel each way.
    fn clamped(&self, part: [u32; 2]) -> [u32; 2] {
        [
            part[0].clamp(1, self.size.width),
            part[1].clamp(1, self.size.height),
        ]
    }

    /// A row of `width` texels padded as buffer copies need (256 bytes).
    fn padded(&self, width: u32) -> u32 {
        let row = self.row_bytes / self.size.width.max(1) * width;
        row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT
    }
}

//! Typed device streams: a storage buffer of `T` (bytemuck `Pod`) and its readback staging.
//! Both are created once and reused every frame.

use std::marker::PhantomData;

use bytemuck::Pod;

use crate::context::GpuContext;
use crate::error::GpuError;

/// A storage buffer of `len` values of `T` on the device.
#[derive(Debug)]
pub struct DeviceStream<T: Pod> {
    buffer: wgpu::Buffer,
    len: usize,
    label: String,
    _element: PhantomData<T>,
}

fn byte_len<T>(len: usize) -> u64 {
    (len.max(1) * std::mem::size_of::<T>()) as u64
}

impl<T: Pod> DeviceStream<T> {
    /// A zeroed stream of `len` values (at least one element is allocated: wgpu has no empty
    /// bindings). Errors when it exceeds the adapter's buffer limits.
    pub fn zeroed(ctx: &GpuContext, label: &str, len: usize) -> Result<Self, GpuError> {
        let bytes = byte_len::<T>(len);
        ctx.check_buffer_size(label, bytes)?;
        let buffer = ctx.scoped(&format!("creating buffer {label}"), || {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_DST
                    | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        })?;
        Ok(Self {
            buffer,
            len,
            label: label.to_string(),
            _element: PhantomData,
        })
    }

    /// A stream holding `data`.
    pub fn from_slice(ctx: &GpuContext, label: &str, data: &[T]) -> Result<Self, GpuError> {
        let stream = Self::zeroed(ctx, label, data.len())?;
        stream.upload(ctx, data)?;
        Ok(stream)
    }

    /// Queues a write of `data` (exactly `len` values); it lands before the next submission.
    pub fn upload(&self, ctx: &GpuContext, data: &[T]) -> Result<(), GpuError> {
        self.check_len(data.len())?;
        if !data.is_empty() {
            ctx.queue
                .write_buffer(&self.buffer, 0, bytemuck::cast_slice(data));
        }
        Ok(())
    }

    /// Queues a write of `data` at value `offset` (the rest of the stream is left as it is).
    pub fn upload_at(&self, ctx: &GpuContext, offset: usize, data: &[T]) -> Result<(), GpuError> {
        if offset + data.len() > self.len {
            return Err(GpuError::LengthMismatch {
                what: format!("stream {} (values {offset}.. written)", self.label),
                expected: self.len.saturating_sub(offset),
                got: data.len(),
            });
        }
        if !data.is_empty() {
            ctx.queue.write_buffer(
                &self.buffer,
                (offset * std::mem::size_of::<T>()) as u64,
                bytemuck::cast_slice(data),
            );
        }
        Ok(())
    }

    fn check_len(&self, got: usize) -> Result<(), GpuError> {
        if got != self.len {
            return Err(GpuError::LengthMismatch {
                what: format!("stream {}", self.label),
                expected: self.len,
                got,
            });
        }
        Ok(())
    }

    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn binding(&self) -> wgpu::BindingResource<'_> {
        self.buffer.as_entire_binding()
    }

    /// Downloads the whole stream (a one-off: allocates a staging buffer). Frame loops use a
    /// [`Readback`] instead.
    pub fn download(&self, ctx: &GpuContext) -> Result<Vec<T>, GpuError> {
        let readback = Readback::new(ctx, &format!("{} readback", self.label), self.len)?;
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        readback.record_copy(&mut encoder, self);
        let index = ctx.queue.submit([encoder.finish()]);
        readback.read(ctx, Some(index))
    }
}

/// A mappable staging buffer for reading `len` values of `T` back, reused every frame.
#[derive(Debug)]
pub struct Readback<T: Pod> {
    staging: wgpu::Buffer,
    len: usize,
    label: String,
    _element: PhantomData<T>,
}

impl<T: Pod> Readback<T> {
    pub fn new(ctx: &GpuContext, label: &str, len: usize) -> Result<Self, GpuError> {
        let bytes = byte_len::<T>(len);
        ctx.check_buffer_size(label, bytes)?;
        let staging = ctx.scoped(&format!("creating staging buffer {label}"), || {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        Ok(Self {
            staging,
            len,
            label: label.to_string(),
            _element: PhantomData,
        })
    }

    /// Records a copy of the first `len` values of `source` into the staging buffer.
    pub fn record_copy(&self, encoder: &mut wgpu::CommandEncoder, source: &DeviceStream<T>) {
        let bytes = (self.len.min(source.len()) * std::mem::size_of::<T>()) as u64;
        if bytes > 0 {
            encoder.copy_buffer_to_buffer(source.buffer(), 0, &self.staging, 0, bytes);
        }
    }

    /// Records a copy of the first `len` values of a raw buffer (a resolved query set, say).
    pub fn record_raw_copy(&self, encoder: &mut wgpu::CommandEncoder, source: &wgpu::Buffer) {
        let bytes = (self.len * std::mem::size_of::<T>()) as u64;
        if bytes > 0 {
            encoder.copy_buffer_to_buffer(source, 0, &self.staging, 0, bytes);
        }
    }

    /// Waits for `submission`, maps the staging buffer and returns its values.
    pub fn read(
        &self,
        ctx: &GpuContext,
        submission: Option<wgpu::SubmissionIndex>,
    ) -> Result<Vec<T>, GpuError> {
        if self.len == 0 {
            return Ok(Vec::new());
        }
        let bytes = (self.len * std::mem::size_of::<T>()) as u64;
        let (sender, receiver) = std::sync::mpsc::channel();
        self.staging
            .map_async(wgpu::MapMode::Read, 0..bytes, move |result| {
                let _ = sender.send(result);
            });
        ctx.wait(submission, &format!("reading back {}", self.label))?;
        let mapped = receiver.recv().map_err(|e| GpuError::Readback {
            what: self.label.clone(),
            message: e.to_string(),
        })?;
        mapped.map_err(|e| GpuError::Readback {
            what: self.label.clone(),
            message: e.to_string(),
        })?;
        let values = {
            let view = self
                .staging
                .get_mapped_range(0..bytes)
                .map_err(|e| GpuError::Readback {
                    what: self.label.clone(),
                    message: e.to_string(),
                })?;
            bytemuck::cast_slice::<u8, T>(&view).to_vec()
        };
        self.staging.unmap();
        Ok(values)
    }
}

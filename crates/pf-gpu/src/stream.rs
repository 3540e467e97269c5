//! Typed device streams: a storage buffer of `T` (bytemuck `Pod`) and its readback staging.
//! Both are created once and reused every frame.

use std::marker::PhantomData;

use bytemuck::Pod;

use crate::context::GpuContext;
use crate::error::GpuError;

/// A uniform buffer holding `value` (a kernel's parameters), created once and bound as is.
pub fn uniform_buffer<T: Pod>(
    ctx: &GpuContext,
    label: &str,
    value: &T,
) -> Result<wgpu::Buffer, GpuError> {
    let buffer = ctx.scoped(&format!("creating the {label}"), || {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: std::mem::size_of::<T>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    })?;
    ctx.queue
        .write_buffer(&buffer, 0, bytemuck::bytes_of(value));
    Ok(buffer)
}

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

    /// Queues a write of raw bytes at byte `offset`, for values packed smaller than `T` (8-bit
    /// pixels in a `u32` stream). Offset and length must be multiples of four bytes.
    pub fn upload_bytes_at(
        &self,
        ctx: &GpuContext,
        offset: usize,
        bytes: &[u8],
    ) -> Result<(), GpuError> {
        let capacity = self.len * std::mem::size_of::<T>();
        if offset + bytes.len() > capacity {
            return Err(GpuError::LengthMismatch {
                what: format!("stream {} (bytes {offset}.. written)", self.label),
                expected: capacity.saturating_sub(offset),
                got: bytes.len(),
            });
        }
        let align = wgpu::COPY_BUFFER_ALIGNMENT as usize;
        if !offset.is_multiple_of(align) || !bytes.len().is_multiple_of(align) {
            return Err(GpuError::InvalidConfig(format!(
                "stream {}: a byte write must start and end on a multiple of {align} (got {} bytes at {offset})",
                self.label,
                bytes.len()
            )));
        }
        if !bytes.is_empty() {
            ctx.queue.write_buffer(&self.buffer, offset as u64, bytes);
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

    /// The wgpu buffer.
    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// Values in the stream.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it holds no values.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The whole buffer as a binding resource.
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
    /// A staging buffer for `len` values of `T`.
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
        let pending = self.request_map();
        ctx.wait(submission, &format!("reading back {}", self.label))?;
        self.collect(pending)
    }

    /// Asks for the staging buffer to be mapped once the queue reaches it. Several readbacks
    /// requested before one [`GpuContext::wait`] share that wait: one poll a frame, not one per
    /// buffer. Finish with [`Readback::collect`] after the wait.
    pub fn request_map(&self) -> PendingMap {
        let (sender, receiver) = std::sync::mpsc::channel();
        if self.len > 0 {
            self.staging
                .map_async(wgpu::MapMode::Read, 0..self.bytes(), move |result| {
                    let _ = sender.send(result);
                });
        }
        PendingMap {
            receiver,
            arrived: None,
        }
    }

    /// The values of a map requested with [`Readback::request_map`], after the wait.
    pub fn collect(&self, pending: PendingMap) -> Result<Vec<T>, GpuError> {
        if self.len == 0 {
            return Ok(Vec::new());
        }
        let bytes = read_mapped(&self.staging, &self.label, pending, 0..self.bytes())?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }

    fn bytes(&self) -> u64 {
        (self.len * std::mem::size_of::<T>()) as u64
    }
}

/// A readback's map request in flight (see [`Readback::request_map`]).
#[derive(Debug)]
pub struct PendingMap {
    receiver: std::sync::mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
    /// The map's outcome once a poll delivered it ([`PendingMap::arrived`]).
    arrived: Option<Result<(), wgpu::BufferAsyncError>>,
}

/// How long [`PendingMap::wait_as_it_lands`] polls before it blocks: several times a face step's
/// GPU time (0.35–0.7 ms on an NVIDIA H100), short beside a body step's (11 ms), whose wait then
/// blocks.
pub const SPIN_BEFORE_BLOCKING: std::time::Duration = std::time::Duration::from_millis(2);

impl PendingMap {
    /// Whether the map has completed (or failed) by the last poll. A readback of nothing maps
    /// nothing (its sender is gone at once): arrived.
    pub fn arrived(&mut self) -> bool {
        if self.arrived.is_none() {
            self.arrived = match self.receiver.try_recv() {
                Ok(result) => Some(result),
                Err(std::sync::mpsc::TryRecvError::Disconnected) => Some(Ok(())),
                Err(std::sync::mpsc::TryRecvError::Empty) => None,
            };
        }
        self.arrived.is_some()
    }

    /// Waits until this map has arrived (its submission and every one before it done): polls
    /// without blocking for up to [`SPIN_BEFORE_BLOCKING`], then blocks in [`GpuContext::wait`]
    /// for `submission`. A short step's results are read the moment they land instead of after
    /// the blocking wait's wake-up (on an NVIDIA H100 a one-face step took 13–21 % less,
    /// docs/BENCHMARKS.md); a long one costs a core only for the spin. For a caller with nothing
    /// else in flight: with a frame queued behind, the blocking wait leaves the cores to the
    /// host's next frame.
    pub fn wait_as_it_lands(
        &mut self,
        ctx: &GpuContext,
        submission: wgpu::SubmissionIndex,
        what: &str,
    ) -> Result<(), GpuError> {
        // On a software adapter the GPU's work runs on the host's cores: no core to spin on.
        let spin = if ctx.adapter().device_type == "CPU (software)" {
            std::time::Duration::ZERO
        } else {
            SPIN_BEFORE_BLOCKING
        };
        self.wait_polling_for(ctx, submission, what, spin)
    }

    /// [`PendingMap::wait_as_it_lands`] with a spin of `spin` whatever the adapter.
    pub fn wait_polling_for(
        &mut self,
        ctx: &GpuContext,
        submission: wgpu::SubmissionIndex,
        what: &str,
        spin: std::time::Duration,
    ) -> Result<(), GpuError> {
        let started = std::time::Instant::now();
        while started.elapsed() < spin {
            // A poll error (a lost device) is the blocking wait's to report.
            if ctx.device.poll(wgpu::PollType::Poll).is_err() {
                break;
            }
            if !self.arrived() {
                std::hint::spin_loop();
                continue;
            }
            // A failed map (a lost device, say): the blocking wait names the cause.
            if matches!(self.arrived, Some(Err(_))) {
                break;
            }
            return ctx.check_lost();
        }
        ctx.wait(Some(submission), what)
    }
}

/// The bytes of `range` of a staging buffer whose map was requested before the wait; unmaps it
/// (also on failure, which ends a map still pending so that the buffer can be mapped again).
fn read_mapped(
    staging: &wgpu::Buffer,
    label: &str,
    mut pending: PendingMap,
    range: std::ops::Range<u64>,
) -> Result<Vec<u8>, GpuError> {
    let failed = |message: String| GpuError::Readback {
        what: label.to_string(),
        message,
    };
    pending.arrived();
    let mapped = match pending.arrived {
        Some(result) => result.map_err(|e| failed(e.to_string())),
        None => Err(failed("the buffer was not mapped by the wait".into())),
    };
    let bytes = mapped.and_then(|()| {
        staging
            .get_mapped_range(range)
            .map(|view| view.to_vec())
            .map_err(|e| failed(e.to_string()))
    });
    staging.unmap();
    bytes
}

/// Several readbacks in one staging buffer: each source is copied into its own section and the
/// frame maps the buffer once (one map and one unmap a frame, not one per stream).
#[derive(Debug)]
pub struct ReadbackSet {
    staging: wgpu::Buffer,
    /// (byte offset, byte length) per section; offsets 8-byte aligned.
    sections: Vec<(u64, u64)>,
    label: String,
}

impl ReadbackSet {
    /// A set with one section of each of `section_bytes` (each a multiple of 4 bytes).
    pub fn new(ctx: &GpuContext, label: &str, section_bytes: &[u64]) -> Result<Self, GpuError> {
        let mut sections = Vec::with_capacity(section_bytes.len());
        let mut end = 0u64;
        for &bytes in section_bytes {
            if !bytes.is_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT) {
                return Err(GpuError::InvalidConfig(format!(
                    "readback {label}: a section of {bytes} bytes is not a whole number of words"
                )));
            }
            let offset = end.next_multiple_of(8);
            sections.push((offset, bytes));
            end = offset + bytes;
        }
        let size = end.max(8);
        ctx.check_buffer_size(label, size)?;
        let staging = ctx.scoped(&format!("creating staging buffer {label}"), || {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        Ok(Self {
            staging,
            sections,
            label: label.to_string(),
        })
    }

    /// Records a copy of the start of `source` into section `section` (its whole length).
    pub fn record_copy(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        section: usize,
        source: &wgpu::Buffer,
    ) {
        self.record_copy_from(encoder, section, source, 0);
    }

    /// Records a copy of `source` from byte `from` on into section `section` (its whole length).
    pub fn record_copy_from(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        section: usize,
        source: &wgpu::Buffer,
        from: u64,
    ) {
        let (offset, bytes) = self.sections[section];
        if bytes > 0 {
            encoder.copy_buffer_to_buffer(source, from, &self.staging, offset, bytes);
        }
    }

    /// As [`Readback::request_map`].
    pub fn request_map(&self) -> PendingMap {
        let (sender, receiver) = std::sync::mpsc::channel();
        self.staging
            .map_async(wgpu::MapMode::Read, .., move |result| {
                let _ = sender.send(result);
            });
        PendingMap {
            receiver,
            arrived: None,
        }
    }

    /// Each section's bytes after the wait, in the order of `new`'s sections (cast them with
    /// `bytemuck::pod_collect_to_vec`).
    pub fn collect(&self, pending: PendingMap) -> Result<Vec<Vec<u8>>, GpuError> {
        let bytes = read_mapped(&self.staging, &self.label, pending, 0..self.staging.size())?;
        Ok(self
            .sections
            .iter()
            .map(|&(offset, len)| bytes[offset as usize..(offset + len) as usize].to_vec())
            .collect())
    }
}

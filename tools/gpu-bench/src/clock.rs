//! Device time between two marks: an empty compute pass writing a timestamp, submitted on the
//! queue before and after the work (wgpu's `TIMESTAMP_QUERY`); without that feature there is no
//! clock and callers report wall time.

use keyframer::gpu::GpuContext;
use keyframer::Result;

/// Two timestamp slots and the buffers their values are resolved into.
pub struct Clock {
    set: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    period_ns: f64,
}

impl Clock {
    /// A clock on `ctx`, when its device has `TIMESTAMP_QUERY`.
    pub fn new(ctx: &GpuContext) -> Option<Clock> {
        if !ctx
            .device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
        {
            return None;
        }
        let set = ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("bench marks"),
            ty: wgpu::QueryType::Timestamp,
            count: 2,
        });
        let resolved = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bench marks resolved"),
            size: 16,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let period_ns = f64::from(ctx.queue.get_timestamp_period());
        Some(Clock {
            set,
            resolved,
            period_ns,
        })
    }

    /// Submits mark `slot` (0: start, 1: end) after everything submitted so far.
    pub fn mark(&self, ctx: &GpuContext, slot: u32) {
        let mut enc = ctx.encoder("bench mark");
        drop(enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("bench mark"),
            timestamp_writes: Some(wgpu::ComputePassTimestampWrites {
                query_set: &self.set,
                beginning_of_pass_write_index: Some(slot),
                end_of_pass_write_index: None,
            }),
        }));
        ctx.queue.submit([enc.finish()]);
    }

    /// Seconds of device time from mark 0 to mark 1 (waits for them).
    pub fn seconds(&self, ctx: &GpuContext) -> Result<f64> {
        let mut enc = ctx.encoder("bench marks resolve");
        enc.resolve_query_set(&self.set, 0..2, &self.resolved, 0);
        ctx.queue.submit([enc.finish()]);
        let bytes = ctx.read_back(&self.resolved, 16)?;
        let at = |k: usize| u64::from_le_bytes(std::array::from_fn(|i| bytes[k * 8 + i]));
        Ok(at(1).saturating_sub(at(0)) as f64 * self.period_ns * 1e-9)
    }
}

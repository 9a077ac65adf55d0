//! Asynchronous readback through pooled staging buffers: a copy is recorded with the work that
//! fills its source, mapped as soon as that work is submitted, and taken once the device got
//! there, oldest first. The host blocks only when asked to, or when every staging buffer of the
//! pool is still in flight.

use super::GpuContext;
use crate::error::{Error, Result};
use std::collections::VecDeque;
use std::sync::mpsc::{channel, Receiver, TryRecvError};

/// The outcome of a buffer's mapping, once wgpu reports it.
pub(crate) type Mapping = Receiver<std::result::Result<(), wgpu::BufferAsyncError>>;

/// Starts mapping the first `bytes` of `staging` for reading.
pub(crate) fn map(staging: &wgpu::Buffer, bytes: u64) -> Mapping {
    let (tx, rx) = channel();
    staging
        .slice(..bytes)
        .map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
    rx
}

/// Whether `m` has completed (waiting for the report with `block`); an error if it failed.
pub(crate) fn mapped(m: &Mapping, block: bool) -> Result<bool> {
    let r = match block {
        true => m.recv().map_err(|_| TryRecvError::Disconnected),
        false => m.try_recv(),
    };
    match r {
        Ok(r) => r
            .map(|_| true)
            .map_err(|e| Error::gpu_from("buffer map failed", e)),
        Err(TryRecvError::Empty) => Ok(false),
        Err(TryRecvError::Disconnected) => Err(Error::gpu("readback callback dropped")),
    }
}

/// How long [`Readback::take`] may block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Until {
    /// Not at all: what has landed.
    Landed,
    /// Until half the pool (rounded up) has landed in this call: a full pool frees half its
    /// buffers with one wait while the device keeps the rest of its work.
    Half,
    /// Until every copy in flight has landed.
    All,
}

struct Flight {
    buffer: wgpu::Buffer,
    bytes: u64,
    submission: wgpu::SubmissionIndex,
    mapping: Mapping,
}

/// A pool of `depth` staging buffers of `size` bytes and the copies in flight through them.
pub struct Readback {
    size: u64,
    depth: usize,
    free: Vec<wgpu::Buffer>,
    /// A copy recorded and not yet submitted.
    recorded: Option<(wgpu::Buffer, u64)>,
    flights: VecDeque<Flight>,
}

impl Readback {
    /// A pool of at most `depth` buffers of `size` bytes, made when first needed.
    pub fn new(size: u64, depth: usize) -> Readback {
        Readback {
            size: size.next_multiple_of(4),
            depth: depth.max(1),
            free: Vec::new(),
            recorded: None,
            flights: VecDeque::new(),
        }
    }

    /// Whether every buffer is in flight ([`Readback::take`] one first).
    pub fn is_full(&self) -> bool {
        self.free.is_empty() && self.flights.len() >= self.depth
    }

    /// Records in `enc` a copy of the first `bytes` of `src` into a staging buffer;
    /// `enc` must then go in through [`Readback::submit`].
    pub fn copy(
        &mut self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        src: &wgpu::Buffer,
        bytes: u64,
    ) -> Result<()> {
        let bytes = bytes.next_multiple_of(4);
        if bytes > self.size || self.is_full() || self.recorded.is_some() {
            return Err(Error::gpu("no staging buffer free for this readback"));
        }
        let buffer =
            (self.free.pop()).unwrap_or_else(|| ctx.staging_buffer("readback pool", self.size));
        enc.copy_buffer_to_buffer(src, 0, &buffer, 0, bytes);
        self.recorded = Some((buffer, bytes));
        Ok(())
    }

    /// Submits `enc`, which holds the recorded copy (if any), and starts mapping that.
    pub fn submit(&mut self, ctx: &GpuContext, enc: wgpu::CommandEncoder) {
        let submission = ctx.queue.submit([enc.finish()]);
        if let Some((buffer, bytes)) = self.recorded.take() {
            let mapping = map(&buffer, bytes);
            self.flights.push_back(Flight {
                buffer,
                bytes,
                submission,
                mapping,
            });
        }
    }

    /// The copies that have landed, oldest first, blocking (one wait) only as far as `until`
    /// asks beyond what has landed already.
    pub fn take(&mut self, ctx: &GpuContext, until: Until) -> Result<Vec<Vec<u8>>> {
        if self.flights.is_empty() {
            return Ok(Vec::new());
        }
        ctx.poll()?;
        let mut out = self.landed(ctx)?;
        let wait = match until {
            Until::Landed => None,
            Until::Half => (self.depth.div_ceil(2))
                .checked_sub(out.len() + 1)
                .and_then(|k| self.flights.get(k)),
            Until::All => self.flights.back(),
        };
        if let Some(f) = wait {
            ctx.wait_for(Some(f.submission.clone()))?;
            out.extend(self.landed(ctx)?);
        }
        Ok(out)
    }

    /// Takes the copies whose mapping completed, oldest first, up to the first that has not.
    fn landed(&mut self, ctx: &GpuContext) -> Result<Vec<Vec<u8>>> {
        let mut out = Vec::new();
        while let Some(f) = self.flights.front() {
            if !mapped(&f.mapping, false)? {
                break;
            }
            if let Some(f) = self.flights.pop_front() {
                out.push(ctx.copy_mapped(&f.buffer, f.bytes)?);
                self.free.push(f.buffer);
            }
        }
        Ok(out)
    }
}

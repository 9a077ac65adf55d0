//! GPU context: picks a wgpu adapter (hardware first, then a software one such as lavapipe, or the
//! one named by `--adapter` / `KEYFRAMER_ADAPTER`), requests downlevel limits raised only where the
//! adapter allows (a tool that needs more asks through [`GpuContext::with_limits`]), caches compute
//! pipelines by name, and uploads / reads back buffers. Faults the device reports (validation
//! errors, device loss) become errors, never panics; [`choice`] resolves the backend to use.

mod choice;

use crate::error::{Error, Result};
pub use choice::{auto_backend, or_opencv, resolve_backend, AdapterClass, AutoDecision};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, LazyLock, Mutex};

pub mod readback;

/// Environment variable naming the adapter to use (case-insensitive substring of its name).
pub const ADAPTER_ENV: &str = "KEYFRAMER_ADAPTER";

/// Test-only: `KEYFRAMER_TEST_GPU_FAULT=1` makes the process's first dispatch ask for more
/// workgroups than the device allows (a validation error), so tests see a real GPU fault taken.
static TEST_FAULT: LazyLock<AtomicBool> = LazyLock::new(|| {
    AtomicBool::new(std::env::var_os("KEYFRAMER_TEST_GPU_FAULT").is_some_and(|v| v == "1"))
});

/// A device and queue plus the adapter facts `keyframer info` reports.
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The adapter the device was made from.
    pub info: wgpu::AdapterInfo,
    /// The limits the device was created with.
    pub limits: wgpu::Limits,
    pipelines: Mutex<HashMap<String, Arc<wgpu::ComputePipeline>>>,
    /// Validation errors and device loss wgpu reported outside any error scope (wgpu's default
    /// handler would panic); [`GpuContext::check`] turns them into an error.
    faults: Arc<Mutex<Vec<String>>>,
    counters: Counters,
}

/// What the host asked of the device so far: the budget issue 16 sets per analysed frame (at
/// most one blocking wait per 16 frames, 1 KiB read back) is checked against these.
#[derive(Debug, Default)]
struct Counters {
    dispatches: AtomicU64,
    uploaded: AtomicU64,
    read_back: AtomicU64,
    waits: AtomicU64,
}

/// A snapshot of a context's counters; subtract two to get the work between them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counts {
    /// Compute dispatches recorded.
    pub dispatches: u64,
    /// Bytes written from the host into device buffers.
    pub uploaded: u64,
    /// Bytes copied from the device to the host.
    pub read_back: u64,
    /// Times the host blocked until the device finished.
    pub waits: u64,
}

impl std::ops::Sub for Counts {
    type Output = Counts;
    fn sub(self, o: Counts) -> Counts {
        Counts {
            dispatches: self.dispatches - o.dispatches,
            uploaded: self.uploaded - o.uploaded,
            read_back: self.read_back - o.read_back,
            waits: self.waits - o.waits,
        }
    }
}

impl std::ops::Add for Counts {
    type Output = Counts;
    fn add(self, o: Counts) -> Counts {
        Counts {
            dispatches: self.dispatches + o.dispatches,
            uploaded: self.uploaded + o.uploaded,
            read_back: self.read_back + o.read_back,
            waits: self.waits + o.waits,
        }
    }
}

/// A context's counters divided by the frames they served.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct PerFrame {
    /// Compute dispatches.
    pub dispatches: f64,
    /// Bytes uploaded.
    pub uploaded: f64,
    /// Bytes read back.
    pub read_back: f64,
    /// Blocking waits for the device.
    pub waits: f64,
}

impl PerFrame {
    /// `c` over `frames` frames.
    pub fn of(c: Counts, frames: usize) -> PerFrame {
        let n = frames.max(1) as f64;
        PerFrame {
            dispatches: c.dispatches as f64 / n,
            uploaded: c.uploaded as f64 / n,
            read_back: c.read_back as f64 / n,
            waits: c.waits as f64 / n,
        }
    }

    /// Columns of `bench`'s tables.
    pub const HEADER: &'static str = "  disp/f  up KiB/f  back B/f  waits/f";

    /// The counters as a row under [`Self::HEADER`].
    pub fn columns(&self) -> String {
        format!(
            " {:>7.1} {:>9.1} {:>9.0} {:>8.3}",
            self.dispatches,
            self.uploaded / 1024.0,
            self.read_back,
            self.waits
        )
    }

    /// Reads what [`PerFrame`]'s `Display` wrote (the end of `select`'s log line).
    pub fn parse(text: &str) -> Option<PerFrame> {
        let mut v = text
            .split(", ")
            .map(|part| part.split_whitespace().next()?.parse::<f64>().ok());
        let mut next = || v.next().flatten();
        Some(PerFrame {
            dispatches: next()?,
            uploaded: next()? * 1024.0,
            read_back: next()?,
            waits: next()?,
        })
    }
}

impl std::fmt::Display for PerFrame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:.1} dispatches, {:.1} KiB uploaded, {:.0} B read back, {:.3} blocking waits per frame",
            self.dispatches,
            self.uploaded / 1024.0,
            self.read_back,
            self.waits
        )
    }
}

/// Facts about one adapter, for `keyframer info`.
#[derive(Debug, Clone, serde::Serialize)]
pub struct AdapterSummary {
    /// Adapter name, e.g. `llvmpipe (LLVM 15.0.6, 256 bits)`.
    pub name: String,
    /// Graphics API (Vulkan, Metal, Dx12, Gl); `backend` in `info --json`, as wgpu names it.
    #[serde(rename = "backend")]
    pub graphics_api: String,
    /// Discrete, integrated, virtual, CPU or other.
    pub device_type: String,
    /// True for software rasterisers ([`AdapterClass::Software`]).
    pub software: bool,
    /// Driver name and version.
    pub driver: String,
    /// Largest storage buffer binding in bytes.
    pub max_storage_buffer_binding_size: u64,
    /// Largest buffer in bytes.
    pub max_buffer_size: u64,
    /// Most invocations in one workgroup.
    pub max_compute_invocations_per_workgroup: u32,
    /// Most workgroups per dispatch dimension.
    pub max_compute_workgroups_per_dimension: u32,
    /// Workgroup shared memory in bytes.
    pub max_compute_workgroup_storage_size: u32,
}

fn rank(t: wgpu::DeviceType) -> u8 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

/// All adapters wgpu finds, best first (hardware before software).
pub fn adapters() -> Vec<wgpu::Adapter> {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::PRIMARY;
    let instance = wgpu::Instance::new(desc);
    let mut list = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::PRIMARY));
    list.sort_by_key(|a| rank(a.get_info().device_type));
    list
}

/// The adapter a context for `wanted` (or `KEYFRAMER_ADAPTER`; else the best) is made on.
pub fn pick_adapter(wanted: Option<&str>) -> Result<wgpu::Adapter> {
    let env = std::env::var(ADAPTER_ENV).ok();
    let wanted = wanted.or(env.as_deref()).filter(|w| !w.is_empty());
    let mut list = adapters();
    if list.is_empty() {
        return Err(Error::gpu(
            "no wgpu adapter found (install mesa-vulkan-drivers for the lavapipe software adapter)",
        ));
    }
    let Some(w) = wanted else {
        return Ok(list.swap_remove(0));
    };
    let lw = w.to_lowercase();
    if let Some(i) = (list.iter()).position(|a| a.get_info().name.to_lowercase().contains(&lw)) {
        return Ok(list.swap_remove(i));
    }
    let names: Vec<String> = list.iter().map(|a| a.get_info().name).collect();
    Err(Error::gpu(format!(
        "no adapter matches `{w}`; available: {}",
        names.join(", ")
    )))
}

/// Summary of an adapter's identity and relevant limits.
pub fn summarize(info: &wgpu::AdapterInfo, limits: &wgpu::Limits) -> AdapterSummary {
    AdapterSummary {
        name: info.name.clone(),
        graphics_api: format!("{:?}", info.backend),
        device_type: format!("{:?}", info.device_type),
        software: AdapterClass::of(info) == AdapterClass::Software,
        driver: format!("{} {}", info.driver, info.driver_info)
            .trim()
            .to_string(),
        max_storage_buffer_binding_size: limits.max_storage_buffer_binding_size,
        max_buffer_size: limits.max_buffer_size,
        max_compute_invocations_per_workgroup: limits.max_compute_invocations_per_workgroup,
        max_compute_workgroups_per_dimension: limits.max_compute_workgroups_per_dimension,
        max_compute_workgroup_storage_size: limits.max_compute_workgroup_storage_size,
    }
}

impl GpuContext {
    /// Creates a device on the preferred adapter with the limits the product's kernels need
    /// (downlevel defaults, storage limits raised as far as the adapter allows). `wanted` (or
    /// `KEYFRAMER_ADAPTER`) selects an adapter by a case-insensitive substring of its name.
    pub fn new(wanted: Option<&str>) -> Result<GpuContext> {
        GpuContext::with_limits(wanted, |_, _| {})
    }

    /// As [`GpuContext::new`], but `raise(limits, adapter)` may raise the requested `limits`
    /// (the product's, see [`GpuContext::new`]) further, up to what the `adapter` offers: for
    /// tools that need more than the product (e.g. the scene renderer's large textures). Asking
    /// for more than the adapter has fails with an error naming the adapter.
    pub fn with_limits(
        wanted: Option<&str>,
        raise: impl FnOnce(&mut wgpu::Limits, &wgpu::Limits),
    ) -> Result<GpuContext> {
        GpuContext::with_options(wanted, wgpu::Features::empty(), raise)
    }

    /// As [`GpuContext::with_limits`], also enabling those of `optional` features the adapter
    /// has (e.g. `TIMESTAMP_QUERY` for a benchmark); `device.features()` says which it got.
    pub fn with_options(
        wanted: Option<&str>,
        optional: wgpu::Features,
        raise: impl FnOnce(&mut wgpu::Limits, &wgpu::Limits),
    ) -> Result<GpuContext> {
        let adapter = pick_adapter(wanted)?;
        let info = adapter.get_info();
        let have = adapter.limits();
        let mut limits = wgpu::Limits::downlevel_defaults();
        limits.max_storage_buffer_binding_size = have.max_storage_buffer_binding_size;
        limits.max_buffer_size = have.max_buffer_size;
        limits.max_storage_buffers_per_shader_stage =
            have.max_storage_buffers_per_shader_stage.min(8);
        limits.max_compute_workgroup_storage_size = have.max_compute_workgroup_storage_size;
        limits.max_texture_dimension_2d = have.max_texture_dimension_2d;
        raise(&mut limits, &have);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("keyframer"),
            required_features: optional & adapter.features(),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| Error::gpu_from(format!("cannot create a device on {}", info.name), e))?;
        let faults = Arc::new(Mutex::new(Vec::new()));
        let sink = faults.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| record(&sink, e.to_string())));
        let sink = faults.clone();
        device.set_device_lost_callback(move |reason, msg| {
            record(&sink, format!("device lost ({reason:?}): {msg}"))
        });
        Ok(GpuContext {
            device,
            queue,
            info,
            limits,
            pipelines: Mutex::new(HashMap::new()),
            faults,
            counters: Counters::default(),
        })
    }

    /// An error naming the first fault wgpu reported on this device since it was made (a
    /// validation error or the device's loss), if any: results read after a fault cannot be
    /// trusted. Called after every wait for the device.
    pub fn check(&self) -> Result<()> {
        let faults = lock(&self.faults, "fault list")?;
        match faults.first() {
            None => Ok(()),
            Some(first) => Err(Error::gpu(format!(
                "the GPU device on {} reported an error ({} in all); its results are not used: {}",
                self.info.name,
                faults.len(),
                first
            ))),
        }
    }

    /// Waits until the device has finished the submitted work, then [`GpuContext::check`]s it.
    pub fn wait(&self) -> Result<()> {
        self.wait_for(None)
    }

    /// Waits until submission `index` (None: all submitted work) has finished, counted as a
    /// blocking wait, then [`GpuContext::check`]s the device.
    pub fn wait_for(&self, index: Option<wgpu::SubmissionIndex>) -> Result<()> {
        self.counters.waits.fetch_add(1, Relaxed);
        self.poll_device(wgpu::PollType::Wait {
            submission_index: index,
            timeout: None,
        })
    }

    /// Runs the callbacks of work that has finished, without blocking (not a wait).
    pub fn poll(&self) -> Result<()> {
        self.poll_device(wgpu::PollType::Poll)
    }

    fn poll_device(&self, how: wgpu::PollType) -> Result<()> {
        self.device
            .poll(how)
            .map_err(|e| Error::gpu_from("device poll failed", e))?;
        self.check()
    }

    /// The counters so far.
    pub fn counts(&self) -> Counts {
        let c = &self.counters;
        Counts {
            dispatches: c.dispatches.load(Relaxed),
            uploaded: c.uploaded.load(Relaxed),
            read_back: c.read_back.load(Relaxed),
            waits: c.waits.load(Relaxed),
        }
    }

    /// Writes `bytes` into `buffer` at `offset` (counted as uploaded).
    pub fn write(&self, buffer: &wgpu::Buffer, offset: u64, bytes: &[u8]) {
        self.counters
            .uploaded
            .fetch_add(bytes.len() as u64, Relaxed);
        self.queue.write_buffer(buffer, offset, bytes);
    }

    /// Counts `bytes` as uploaded by a path that bypasses [`GpuContext::write`] (the frames'
    /// staging belt, `kernels::strip::upload`).
    pub fn count_upload(&self, bytes: u64) {
        self.counters.uploaded.fetch_add(bytes, Relaxed);
    }

    /// Records `pipe` with bind group `bg` over `groups` (x, y) workgroups (counted).
    pub fn dispatch(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        pipe: &wgpu::ComputePipeline,
        bg: &wgpu::BindGroup,
        groups: (u32, u32),
    ) {
        self.dispatch_gated(pass, (pipe, bg), groups, None, 0);
    }

    /// As [`GpuContext::dispatch`], or, with a `gate`, over the workgroups in its entry `shape`
    /// (written on the device; counted as a dispatch even when they are 0).
    pub fn dispatch_gated(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        (pipe, bg): (&wgpu::ComputePipeline, &wgpu::BindGroup),
        groups: (u32, u32),
        gate: Option<Gate<'_>>,
        shape: usize,
    ) {
        self.counters.dispatches.fetch_add(1, Relaxed);
        pass.set_pipeline(pipe);
        pass.set_bind_group(0, bg, &[]);
        if let Some(g) = gate {
            return pass.dispatch_workgroups_indirect(g.args, 12 * (g.first + shape) as u64);
        }
        let groups = match TEST_FAULT.swap(false, Relaxed) {
            true => (
                self.limits
                    .max_compute_workgroups_per_dimension
                    .saturating_add(1),
                1,
            ),
            false => groups,
        };
        pass.dispatch_workgroups(groups.0, groups.1, 1);
    }

    /// Summary of the adapter and the device limits.
    pub fn summary(&self) -> AdapterSummary {
        summarize(&self.info, &self.limits)
    }

    /// The compute pipeline for `entry` in shader `name` (WGSL `source`), compiled once.
    pub fn pipeline(
        &self,
        name: &str,
        source: &str,
        entry: &str,
    ) -> Result<Arc<wgpu::ComputePipeline>> {
        let key = format!("{name}:{entry}");
        let mut map = lock(&self.pipelines, "pipeline cache")?;
        if let Some(p) = map.get(&key) {
            return Ok(p.clone());
        }
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(name),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        let p = Arc::new(
            self.device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(&key),
                    layout: None,
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                }),
        );
        map.insert(key, p.clone());
        Ok(p)
    }

    /// A storage buffer of `size` bytes (rounded up to 4) usable as copy source and destination.
    pub fn storage_buffer(&self, label: &str, size: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size.max(4).next_multiple_of(4),
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        })
    }

    /// A storage buffer holding `bytes` that dispatches can also take their workgroup counts from
    /// ([`GpuContext::dispatch_indirect`]).
    pub fn indirect_buffer(&self, label: &str, bytes: &[u8]) -> wgpu::Buffer {
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDIRECT;
        self.buffer_init(label, usage, bytes)
    }

    /// A buffer holding `bytes` (size rounded up to 4, at least 16) with `usage` and COPY_DST.
    pub fn buffer_init(
        &self,
        label: &str,
        usage: wgpu::BufferUsages,
        bytes: &[u8],
    ) -> wgpu::Buffer {
        let buf = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: (bytes.len() as u64).next_multiple_of(4).max(16),
            usage: usage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.write(&buf, 0, bytes);
        buf
    }

    /// A uniform buffer holding `v`.
    pub fn uniform<T: bytemuck::Pod>(&self, label: &str, v: &T) -> wgpu::Buffer {
        self.buffer_init(label, wgpu::BufferUsages::UNIFORM, bytemuck::bytes_of(v))
    }

    /// A bind group of `pipe`'s group 0 binding each buffer whole at its index.
    pub fn bind(
        &self,
        label: &str,
        pipe: &wgpu::ComputePipeline,
        entries: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let entries: Vec<_> = entries
            .iter()
            .map(|(b, buf)| (*b, buf.as_entire_binding()))
            .collect();
        self.bind_resources(label, pipe, &entries)
    }

    /// As [`GpuContext::bind`], for any binding resources (e.g. part of a buffer).
    pub fn bind_resources(
        &self,
        label: &str,
        pipe: &wgpu::ComputePipeline,
        entries: &[(u32, wgpu::BindingResource<'_>)],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry<'_>> = entries
            .iter()
            .map(|(binding, r)| wgpu::BindGroupEntry {
                binding: *binding,
                resource: r.clone(),
            })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &pipe.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// A 2-D `width` x `height` texture of one mip level and one sample.
    pub fn texture(
        &self,
        label: &str,
        (width, height): (u32, u32),
        format: wgpu::TextureFormat,
        usage: wgpu::TextureUsages,
    ) -> wgpu::Texture {
        self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    }

    /// A command encoder labelled `label`.
    pub fn encoder(&self, label: &str) -> wgpu::CommandEncoder {
        self.device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) })
    }

    /// Writes `bytes` (rows of `bytes_per_row`, whole texels) into all of `texture` (counted as
    /// uploaded).
    pub fn write_texture(&self, texture: &wgpu::Texture, bytes: &[u8], bytes_per_row: u32) {
        self.counters
            .uploaded
            .fetch_add(bytes.len() as u64, Relaxed);
        self.queue.write_texture(
            texture.as_image_copy(),
            bytes,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(bytes_per_row),
                rows_per_image: None,
            },
            texture.size(),
        );
    }

    /// Copies the first `size` bytes of `buffer` to the host (submits and waits; the copy, and
    /// the bytes counted as read back, are rounded up to 4).
    pub fn read_back(&self, buffer: &wgpu::Buffer, size: u64) -> Result<Vec<u8>> {
        let rounded = size.next_multiple_of(4);
        let staging = self.staging_buffer("readback", rounded);
        let mut enc = self.encoder("readback");
        enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, rounded);
        self.queue.submit([enc.finish()]);
        let mut bytes = self.map_and_copy(&staging)?;
        bytes.truncate(size as usize);
        Ok(bytes)
    }

    /// A MAP_READ buffer of `size` bytes that copies can land in.
    pub fn staging_buffer(&self, label: &str, size: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Maps a MAP_READ buffer whose copies were already submitted, and copies it out.
    pub fn map_and_copy(&self, staging: &wgpu::Buffer) -> Result<Vec<u8>> {
        let mapped = readback::map(staging, staging.size());
        self.wait()?;
        readback::mapped(&mapped, true)?;
        self.copy_mapped(staging, staging.size())
    }

    /// Copies the first `bytes` of a mapped MAP_READ buffer to the host (counted as read back)
    /// and unmaps it.
    pub fn copy_mapped(&self, staging: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>> {
        let out = staging
            .slice(..bytes)
            .get_mapped_range()
            .map_err(|e| Error::gpu_from("mapped range", e))?
            .to_vec();
        staging.unmap();
        self.counters.read_back.fetch_add(out.len() as u64, Relaxed);
        Ok(out)
    }
}

/// A host image the runners upload: 8-bit pixels, `channels` per pixel (1: gray, 3: BGR), rows
/// packed. An OpenCV `Mat` (with the `opencv` feature) and a plain byte slice both are one.
pub trait HostImage {
    /// The pixel bytes, checked to be `channels` x `size` (width, height); `what` names the
    /// runner in errors. Borrowed where the pixels are contiguous.
    fn pixel_bytes(
        &self,
        channels: u32,
        size: (u32, u32),
        what: &str,
    ) -> Result<std::borrow::Cow<'_, [u8]>>;
}

/// Rows of `width * channels` bytes, one after the other (the size is checked by length).
impl HostImage for [u8] {
    fn pixel_bytes(
        &self,
        channels: u32,
        (width, height): (u32, u32),
        what: &str,
    ) -> Result<std::borrow::Cow<'_, [u8]>> {
        let want = width as usize * height as usize * channels as usize;
        if self.len() != want {
            return Err(Error::gpu(format!(
                "frame has {} bytes; the {what} runner takes {width}x{height} with {channels} \
                 channel(s), {want} bytes",
                self.len()
            )));
        }
        Ok(std::borrow::Cow::Borrowed(self))
    }
}

#[cfg(feature = "opencv")]
impl HostImage for opencv::core::Mat {
    fn pixel_bytes(
        &self,
        channels: u32,
        size: (u32, u32),
        what: &str,
    ) -> Result<std::borrow::Cow<'_, [u8]>> {
        let typ = match channels {
            1 => opencv::core::CV_8UC1,
            _ => opencv::core::CV_8UC3,
        };
        mat_bytes(self, typ, size, what)
    }
}

/// The pixel bytes of `mat`, checked to be of type `typ` and `size` (width, height); `what`
/// names the runner in errors. Borrowed when `mat` is continuous.
#[cfg(feature = "opencv")]
pub fn mat_bytes<'a>(
    mat: &'a opencv::core::Mat,
    typ: i32,
    (width, height): (u32, u32),
    what: &str,
) -> Result<std::borrow::Cow<'a, [u8]>> {
    use opencv::prelude::*;
    if mat.typ() != typ || mat.cols() as u32 != width || mat.rows() as u32 != height {
        return Err(Error::gpu(format!(
            "frame is {}x{} of type {}; the {what} runner takes {width}x{height} of type {typ}",
            mat.cols(),
            mat.rows(),
            mat.typ()
        )));
    }
    let cv = |e: opencv::Error| Error::gpu_from(format!("reading the {what} frame"), e);
    if mat.is_continuous() {
        return mat.data_bytes().map(std::borrow::Cow::Borrowed).map_err(cv);
    }
    let owned = mat.try_clone().map_err(cv)?;
    Ok(std::borrow::Cow::Owned(
        owned.data_bytes().map_err(cv)?.to_vec(),
    ))
}

/// Dispatch sizes the device writes ([x, y, z] u32 per entry; zeros skip the dispatch): an
/// encoder's gated dispatches read entry `first + shape`, `shape` the index of their size in the
/// list the encoder publishes.
#[derive(Clone, Copy)]
pub struct Gate<'a> {
    /// The buffer of dispatch sizes.
    pub args: &'a wgpu::Buffer,
    /// The encoder's first entry in it.
    pub first: usize,
}

/// A compute pass of `enc` labelled `label`.
pub fn compute_pass<'a>(enc: &'a mut wgpu::CommandEncoder, label: &str) -> wgpu::ComputePass<'a> {
    enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(label),
        timestamp_writes: None,
    })
}

/// Keeps the first few faults (the first one explains the rest), each on one line: wgpu's
/// "Validation Error / Caused by: / In a … / the rule broken" joined by ": ".
fn record(faults: &Mutex<Vec<String>>, msg: String) {
    if let Ok(mut f) = faults.lock() {
        if f.len() < 8 {
            log::debug!("gpu fault: {msg}");
            let lines: Vec<&str> = msg
                .lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && *l != "Caused by:")
                .collect();
            f.push(lines.join(": "));
        }
    }
}

/// `m` locked; an error naming it (`what`) when a thread panicked holding it.
fn lock<'a, T>(m: &'a Mutex<T>, what: &str) -> Result<std::sync::MutexGuard<'a, T>> {
    m.lock()
        .map_err(|_| Error::gpu(format!("{what} lock poisoned")))
}

/// The process's context for `adapter` (see [`resolve_backend`]).
fn shared(adapter: Option<&str>) -> Result<Arc<GpuContext>> {
    static SHARED: Mutex<Vec<(Option<String>, Arc<GpuContext>)>> = Mutex::new(Vec::new());
    let key = adapter.map(str::to_string);
    let mut list = lock(&SHARED, "context list")?;
    list.retain(|(_, c)| c.check().is_ok());
    if let Some((_, c)) = list.iter().find(|(k, _)| *k == key) {
        return Ok(c.clone());
    }
    let ctx = Arc::new(GpuContext::new(adapter)?);
    log::info!(
        "gpu backend on {} ({:?}, {:?})",
        ctx.info.name,
        ctx.info.backend,
        ctx.info.device_type
    );
    list.push((key, ctx.clone()));
    Ok(ctx)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dispatch over the device's workgroup limit is a validation error: `wait` and `check`
    /// return it (naming the adapter and wgpu's cause), nothing panics, later reads fail.
    #[test]
    fn a_validation_error_is_an_error_not_a_panic() {
        let ctx = GpuContext::new(None).expect("a wgpu adapter (lavapipe in CI)");
        let src = "@group(0) @binding(0) var<storage, read_write> b: array<u32>;\n\
                   @compute @workgroup_size(1) fn main() { b[0] = 1u; }";
        let pipe = ctx.pipeline("fault", src, "main").expect("pipeline");
        let buf = ctx.storage_buffer("fault", 4);
        let bg = ctx.bind("fault", &pipe, &[(0, &buf)]);
        assert!(ctx.check().is_ok(), "a fresh context has no fault");
        let mut enc = ctx.encoder("fault");
        {
            let mut pass = compute_pass(&mut enc, "fault");
            let over = ctx.limits.max_compute_workgroups_per_dimension + 1;
            ctx.dispatch(&mut pass, &pipe, &bg, (over, 1));
        }
        ctx.queue.submit([enc.finish()]);
        let waited = ctx.wait().expect_err("the over-limit dispatch is reported");
        assert!(matches!(waited, Error::Gpu { .. }), "{waited}");
        let msg = waited.to_string();
        assert!(msg.contains(&ctx.info.name), "{msg}");
        assert!(msg.contains("dispatch group size dimension"), "{msg}");
        let checked = ctx.check().expect_err("the fault stays recorded");
        assert_eq!(checked.to_string(), waited.to_string());
        assert!(ctx.read_back(&buf, 4).is_err(), "reads after a fault fail");
    }
}

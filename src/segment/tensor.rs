//! Turns images into the network's input tensor and its output tensor into per-pixel class
//! indices, identically for every runtime (so backends differ only in the network itself).

use super::desc::{ChannelOrder, Layout, ModelDesc, OutputKind};
use crate::error::{CvContext, Error, Result};
use opencv::core::Mat;
use opencv::imgproc;
use opencv::prelude::*;

/// Shape of the input tensor for `n` images.
pub fn input_shape(desc: &ModelDesc, n: usize) -> [usize; 4] {
    let (w, h) = (desc.input.width as usize, desc.input.height as usize);
    match desc.input.layout {
        Layout::Nchw => [n, 3, h, w],
        Layout::Nhwc => [n, h, w, 3],
    }
}

/// Appends the input tensor values of one 8-bit BGR image to `out`: resized (bilinear) to the
/// model's size, channels reordered, `(v * scale - mean) / std`, in the model's layout.
pub fn push_image(desc: &ModelDesc, image: &Mat, out: &mut Vec<f32>) -> Result<()> {
    push_resized(desc, image, imgproc::INTER_LINEAR, out)
}

/// [`push_image`] with the resize's interpolation `interp` (an OpenCV `INTER_*`).
pub fn push_resized(desc: &ModelDesc, image: &Mat, interp: i32, out: &mut Vec<f32>) -> Result<()> {
    let (w, h) = (desc.input.width as i32, desc.input.height as i32);
    if image.channels() != 3 || image.depth() != opencv::core::CV_8U {
        let msg = "segmentation needs an 8-bit, 3-channel image";
        return Err(Error::param("image", msg));
    }
    let resized;
    let img = if image.cols() == w && image.rows() == h {
        image
    } else {
        resized = crate::encode::resize(image, (w, h), interp)
            .cv(|| format!("resize to the model's {w}x{h}"))?;
        &resized
    };
    let cont;
    let img = if img.is_continuous() {
        img
    } else {
        cont = img.try_clone().cv(|| "copy".into())?;
        &cont
    };
    let px = img.data_bytes().cv(|| "image data".into())?;
    let i = &desc.input;
    // Model channel k reads BGR channel src[k].
    let src = match i.channels {
        ChannelOrder::Rgb => [2usize, 1, 0],
        ChannelOrder::Bgr => [0usize, 1, 2],
    };
    let value =
        |p: usize, k: usize| (f32::from(px[p * 3 + src[k]]) * i.scale - i.mean[k]) / i.std[k];
    let n = (w * h) as usize;
    match i.layout {
        Layout::Nchw => {
            for k in 0..3 {
                out.extend((0..n).map(|p| value(p, k)));
            }
        }
        Layout::Nhwc => {
            for p in 0..n {
                for k in 0..3 {
                    out.push(value(p, k));
                }
            }
        }
    }
    Ok(())
}

/// An output tensor as a runtime returns it: its shape and its values.
pub type Output = (Vec<usize>, Vec<f32>);

/// Class index maps (one `u16` per pixel, row-major) decoded from an output tensor.
pub struct ClassMaps {
    /// Width of each map.
    pub width: usize,
    /// Height of each map.
    pub height: usize,
    /// One map per image.
    pub maps: Vec<Vec<u16>>,
}

/// Interprets an output tensor of `shape` for `n` images. Accepted shapes: 4-D in the output
/// layout, or 3-D `[n, h, w]` for a single channel.
pub fn decode_output(
    desc: &ModelDesc,
    shape: &[usize],
    data: &[f32],
    n: usize,
) -> Result<ClassMaps> {
    let want_c = desc.output_channels();
    let (bn, c, h, w, nchw) = match (shape, desc.output_layout()) {
        ([b, c, h, w], Layout::Nchw) => (*b, *c, *h, *w, true),
        ([b, h, w, c], Layout::Nhwc) => (*b, *c, *h, *w, false),
        ([b, h, w], _) => (*b, 1, *h, *w, true),
        _ => {
            return Err(mismatch(
                desc,
                format!("output shape {shape:?} is not 3-D or 4-D"),
            ))
        }
    };
    if bn != n {
        let msg = format!("output batch is {bn} for {n} input images");
        return Err(mismatch(desc, msg));
    }
    if c != want_c {
        return Err(mismatch(
            desc,
            format!(
                "the output has {c} channels ({:?} {shape:?}); the description expects {want_c} ({} classes, kind {:?})",
                desc.output_layout(),
                desc.classes.len(),
                desc.output.kind
            ),
        ));
    }
    if data.len() != bn * c * h * w || h == 0 || w == 0 {
        let msg = format!("output has {} values for shape {shape:?}", data.len());
        return Err(mismatch(desc, msg));
    }
    let plane = h * w;
    let at = |b: usize, k: usize, p: usize| {
        if nchw {
            data[(b * c + k) * plane + p]
        } else {
            data[(b * plane + p) * c + k]
        }
    };
    let maps = (0..n)
        .map(|b| {
            (0..plane)
                .map(|p| match desc.output.kind {
                    OutputKind::Probability => u16::from(at(b, 0, p) >= desc.output.threshold),
                    // Refused by `Segmenter::new`: an embedding has no classes.
                    OutputKind::Embedding => 0,
                    // First maximum wins, so ties resolve the same way everywhere.
                    OutputKind::Scores => (1..c).fold(0, |best, k| {
                        if at(b, k, p) > at(b, best, p) {
                            k
                        } else {
                            best
                        }
                    }) as u16,
                })
                .collect()
        })
        .collect();
    Ok(ClassMaps {
        width: w,
        height: h,
        maps,
    })
}

/// An error saying the description does not fit the model.
pub fn mismatch(desc: &ModelDesc, msg: String) -> Error {
    Error::step(
        "segment",
        format!(
            "{} does not match {}: {msg}",
            desc.path.display(),
            desc.model.display()
        ),
    )
}

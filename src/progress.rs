//! Progress bars on stderr (hidden with `--quiet` or when stderr is not a terminal).

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A bar for `len` items (0: unknown length) labelled `what`, showing rate and ETA.
pub fn bar(len: u64, what: &str, quiet: bool) -> ProgressBar {
    let pb = if len == 0 {
        ProgressBar::no_length()
    } else {
        ProgressBar::new(len)
    };
    if quiet {
        pb.set_draw_target(ProgressDrawTarget::hidden());
    } else {
        pb.set_draw_target(ProgressDrawTarget::stderr());
    }
    let template = if len == 0 {
        "{msg:>8} {pos} frames {per_sec} {elapsed}"
    } else {
        "{msg:>8} [{bar:30}] {pos}/{len} {per_sec} ETA {eta}"
    };
    if let Ok(style) = ProgressStyle::with_template(template) {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(what.to_string());
    pb
}

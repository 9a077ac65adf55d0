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

/// A spinner for a task of unknown length labelled `what`, showing the elapsed time (ticking on
/// its own thread until finished).
pub fn spinner(what: &str, quiet: bool) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    if quiet {
        pb.set_draw_target(ProgressDrawTarget::hidden());
        return pb;
    }
    pb.set_draw_target(ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} {elapsed}") {
        pb.set_style(style);
    }
    pb.set_message(what.to_string());
    pb.enable_steady_tick(std::time::Duration::from_millis(200));
    pb
}

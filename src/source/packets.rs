//! A video's packet list from `ffprobe` (demuxing only, no decode) turned into what FFmpeg's
//! decoder stamps on each frame, in display order: the best-effort timestamp (`ffprobe
//! -show_frames`' `best_effort_timestamp`: the pts, or the decode time once the pts repeat or go
//! back) and the position OpenCV 4.6's FFmpeg backend reports for the frame (to check that
//! decoded frames and listed packets pair). The list is read from ffprobe's pipe line by line;
//! what is kept is two numbers per frame. [`ffprobe`] runs ffprobe for the preview's list too.

use crate::error::{Error, Result};
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// Seconds by which a frame whose best-effort time does not increase (a repeated pts) is placed
/// after the previous frame, so that timestamps increase strictly.
pub const REPEAT_STEP_S: f64 = 1e-6;

/// Per-frame times of a video's first video stream, in display order.
#[derive(Debug, Clone, PartialEq)]
pub struct StreamTimes {
    /// Seconds from the first frame: the best-effort timestamp, strictly increasing.
    pub timestamps_s: Vec<f64>,
    /// OpenCV 4.6's `CAP_PROP_POS_MSEC` / 1000 for the frame: the pts (the decode time where
    /// the pts is missing or 0) minus the stream's start; 0 where neither exists.
    pub opencv_s: Vec<f64>,
    /// Half a tick of the stream's time base, in seconds: closer times are the same time.
    pub tolerance_s: f64,
    /// Frames whose best-effort time did not increase (placed [`REPEAT_STEP_S`] after the
    /// previous frame).
    pub repeated: Vec<usize>,
}

impl StreamTimes {
    /// Whether OpenCV's position `pos_s` of the frame decoded as `index` is the position listed
    /// for it, both taken from frame 0's (`origin_s`); `None` when OpenCV gives none (0 past
    /// frame 0: the frames drained from the decoder at the end of the stream) or the list
    /// holds no frame `index`.
    pub fn pairs(&self, index: usize, pos_s: f64, origin_s: f64) -> Option<bool> {
        let listed = *self.opencv_s.get(index)?;
        if (index > 0 && pos_s == 0.0) || !pos_s.is_finite() {
            return None;
        }
        let first = self.opencv_s.first().copied().unwrap_or(0.0);
        Some(((pos_s - origin_s) - (listed - first)).abs() <= self.tolerance_s)
    }
}

/// One packet of the list, in decode order (times in time-base ticks).
struct Packet {
    pts: Option<i64>,
    dts: Option<i64>,
    /// Decoded but never shown (an edit list cuts it).
    discard: bool,
}

/// Lists the packets of `path`'s first video stream with `ffprobe` and derives the frame times.
pub fn list(path: &Path) -> Result<StreamTimes> {
    list_until(path, &AtomicBool::new(false))
}

/// [`list`], given up (ffprobe killed) as soon as `cancel` is set.
fn list_until(path: &Path, cancel: &AtomicBool) -> Result<StreamTimes> {
    let entries = "stream=time_base,start_pts,codec_name,has_b_frames:packet=pts,dts,flags";
    ffprobe(path, &["-show_entries", entries, "-of", "compact"], |out| {
        let mut out = Cancellable { inner: out, cancel };
        parse(path, &mut out)
    })
}

/// A reader that fails once `cancel` is set (so that the parse stops and ffprobe is killed).
struct Cancellable<'a, 'b> {
    inner: &'a mut dyn BufRead,
    cancel: &'b AtomicBool,
}

impl Cancellable<'_, '_> {
    fn check(&self) -> std::io::Result<()> {
        match self.cancel.load(Ordering::Relaxed) {
            true => Err(std::io::Error::other("the packet list is no longer wanted")),
            false => Ok(()),
        }
    }
}

impl Read for Cancellable<'_, '_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.check()?;
        self.inner.read(buf)
    }
}

impl BufRead for Cancellable<'_, '_> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        self.check()?;
        self.inner.fill_buf()
    }

    fn consume(&mut self, amount: usize) {
        self.inner.consume(amount)
    }
}

/// A packet list being read in the background from the moment a video is opened, so that
/// ffprobe's pass over the file overlaps the decode instead of holding up the second frame.
/// Dropping it unwaited stops ffprobe.
pub struct Listing {
    path: PathBuf,
    cancel: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<StreamTimes>>>,
}

impl Listing {
    /// Starts listing `path`'s packets on a thread of its own.
    pub fn start(path: &Path) -> Listing {
        let cancel = Arc::new(AtomicBool::new(false));
        let (p, c) = (path.to_path_buf(), cancel.clone());
        let thread = std::thread::Builder::new()
            .name("packet-list".into())
            .spawn(move || list_until(&p, &c));
        Listing {
            path: path.to_path_buf(),
            cancel,
            // A thread that cannot start: the list is read when waited for.
            thread: thread.ok(),
        }
    }

    /// The list, once ffprobe is done.
    pub fn wait(mut self) -> Result<StreamTimes> {
        match self.thread.take() {
            Some(t) => t.join().unwrap_or_else(|_| {
                Err(Error::input(
                    &self.path,
                    "the packet listing thread panicked",
                ))
            }),
            None => list(&self.path),
        }
    }
}

impl Drop for Listing {
    fn drop(&mut self) {
        self.cancel.store(true, Ordering::Relaxed);
    }
}

/// Runs `ffprobe -v error -select_streams v:0 ARGS PATH` and hands its output, as it comes, to
/// `read`; an error names the missing tool or repeats ffprobe's message.
pub fn ffprobe<T>(
    path: &Path,
    args: &[&str],
    read: impl FnOnce(&mut dyn BufRead) -> Result<T>,
) -> Result<T> {
    let mut child = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0"])
        .args(args)
        .arg(path)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| {
            let msg = format!(
                "cannot run `ffprobe` ({e}); FFmpeg's command-line tools are needed \
                 (Debian/Ubuntu: apt-get install ffmpeg)"
            );
            Error::input(path, msg)
        })?;
    let (stdout, stderr) = (child.stdout.take(), child.stderr.take());
    let (parsed, err) = std::thread::scope(|scope| {
        let err = scope.spawn(move || {
            let mut text = String::new();
            if let Some(mut e) = stderr {
                let _ = e.read_to_string(&mut text);
            }
            text
        });
        let parsed = match stdout {
            Some(out) => read(&mut BufReader::new(out)),
            None => Err(Error::input(path, "ffprobe started without an output pipe")),
        };
        // A reader that stopped early must not leave ffprobe blocked on a full pipe.
        if parsed.is_err() {
            let _ = child.kill();
        }
        (parsed, err.join().unwrap_or_default())
    });
    let status = child.wait().map_err(|e| Error::io(path, e))?;
    if !status.success() {
        let msg = format!("ffprobe cannot list the packets: {}", err.trim());
        return Err(Error::input(path, msg));
    }
    parsed
}

/// Parses `ffprobe -show_entries stream=time_base,start_pts,codec_name,has_b_frames:packet=pts,dts,flags -of compact`
/// output (`packet|pts=..|dts=..|flags=K_` lines in decode order, one `stream|..` line).
pub fn parse(path: &Path, text: &mut dyn BufRead) -> Result<StreamTimes> {
    let mut packets = Vec::new();
    let mut time_base = None;
    let mut start = 0i64;
    // H.264's declared reorder depth (the frames its decoder holds back); 0 when not listed.
    let mut reorder = 0usize;
    for (n, line) in text.split(b'\n').enumerate() {
        let line = line.map_err(|e| Error::io(path, e))?;
        let line = String::from_utf8_lossy(&line);
        let bad = |what: String| Error::input(path, format!("ffprobe line {}: {what}", n + 1));
        let mut fields = line.trim().split('|');
        let section = fields.next().unwrap_or_default();
        let get = |key: &str| {
            let mut found = None;
            for f in fields.clone() {
                if let Some(v) = f.strip_prefix(key).and_then(|r| r.strip_prefix('=')) {
                    found = Some(v.to_string());
                }
            }
            found.ok_or_else(|| bad(format!("no `{key}` in `{line}`")))
        };
        let ticks = |v: String| match v.as_str() {
            "N/A" => Ok(None),
            t => t.parse::<i64>().map(Some),
        };
        match section {
            "packet" => {
                let (pts, dts, flags) = (get("pts")?, get("dts")?, get("flags")?);
                let time = |v: String| ticks(v.clone()).map_err(|_| bad(format!("bad time `{v}`")));
                packets.push(Packet {
                    pts: time(pts)?,
                    dts: time(dts)?,
                    discard: flags.contains('D'),
                });
            }
            "stream" if time_base.is_none() => {
                let tb = get("time_base")?;
                let parsed = tb.split_once('/').and_then(|(a, b)| {
                    let (a, b) = (a.parse::<i64>().ok()?, b.parse::<i64>().ok()?);
                    (a > 0 && b > 0).then_some((a, b))
                });
                time_base = Some(parsed.ok_or_else(|| bad(format!("bad time base `{tb}`")))?);
                start = ticks(get("start_pts")?).ok().flatten().unwrap_or(0);
                if get("codec_name").is_ok_and(|c| c == "h264") {
                    let depth = get("has_b_frames").ok().and_then(|v| v.parse().ok());
                    reorder = depth.unwrap_or(0);
                }
            }
            _ => {}
        }
    }
    let Some((num, den)) = time_base else {
        return Err(Error::input(path, "ffprobe lists no video stream"));
    };
    times(path, packets, num as f64 / den as f64, start, reorder)
}

/// The frame times of `packets` (decode order) in a stream with time base `tb` seconds and
/// start `start` ticks: FFmpeg's decoder outputs frames in pts order, `delay` packets after
/// their own, each carrying the decode time of the packet fed last. `delay` is the deepest
/// reordering in the list, or H.264's declared depth `reorder` where that is more: its decoder
/// holds frames back that far even in a clip too short to reorder so deep (x264's defaults
/// declare 2; a 10-frame clip reorders 1 deep). Not for other codecs: MPEG-4 part 2 in AVI
/// declares 1 and pairs with the list's own depth.
fn times(
    path: &Path,
    packets: Vec<Packet>,
    tb: f64,
    start: i64,
    reorder: usize,
) -> Result<StreamTimes> {
    let all = packets.len();
    let packets: Vec<Packet> = packets
        .into_iter()
        .filter(|p| p.pts.is_some() || p.dts.is_some())
        .collect();
    if packets.len() < all {
        log::debug!(
            "{}: {} packets carry neither a presentation nor a decode time; left out",
            path.display(),
            all - packets.len()
        );
    }
    if packets.is_empty() {
        return Err(Error::input(path, "ffprobe lists no video packets"));
    }
    // Where a container stores no pts (AVI's I and P frames), display order is decode order.
    let sort_time = |p: &Packet| p.pts.or(p.dts).unwrap_or(0);
    let mut order: Vec<usize> = (0..packets.len()).collect();
    order.sort_by_key(|&i| sort_time(&packets[i]));
    let delay = order.iter().enumerate().map(|(k, &j)| j.saturating_sub(k));
    let delay = delay.max().unwrap_or(0).max(reorder);
    let secs = |t: i64| t as f64 * tb;
    let (mut best, mut opencv_s) = (Vec::new(), Vec::new());
    // FFmpeg's guess_correct_pts (libavcodec/decode.c), frame by frame.
    let (mut last_pts, mut last_dts, mut faulty_pts, mut faulty_dts) = (i64::MIN, i64::MIN, 0, 0);
    for (k, &j) in order.iter().enumerate() {
        let p = &packets[j];
        if p.discard {
            continue;
        }
        let (pts, dts) = (p.pts, packets.get(k + delay).and_then(|q| q.dts));
        match (dts, pts) {
            (Some(d), _) => (faulty_dts, last_dts) = (faulty_dts + usize::from(d <= last_dts), d),
            (None, Some(t)) => last_dts = t,
            (None, None) => {}
        }
        match (pts, dts) {
            (Some(t), _) => (faulty_pts, last_pts) = (faulty_pts + usize::from(t <= last_pts), t),
            (None, Some(d)) => last_pts = d,
            (None, None) => {}
        }
        best.push(match (pts, dts) {
            (Some(t), d) if faulty_pts <= faulty_dts || d.is_none() => t,
            (_, Some(d)) => d,
            _ => sort_time(p),
        });
        let shown = pts.filter(|&t| t != 0).or(dts);
        opencv_s.push(shown.map_or(0.0, |t| secs(t - start)));
    }
    let t0 = best.first().copied().unwrap_or(0);
    let (mut timestamps_s, mut repeated) = (Vec::with_capacity(best.len()), Vec::new());
    for (i, &b) in best.iter().enumerate() {
        let t = secs(b - t0);
        match timestamps_s.last() {
            Some(&prev) if t <= prev => {
                repeated.push(i);
                timestamps_s.push(prev + REPEAT_STEP_S);
            }
            _ => timestamps_s.push(t),
        }
    }
    Ok(StreamTimes {
        timestamps_s,
        opencv_s,
        tolerance_s: 0.5 * tb,
        repeated,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn times_of(lines: &str) -> StreamTimes {
        let text = format!("{lines}\nstream|time_base=1/100|start_pts=0\n");
        parse(Path::new("v.mp4"), &mut text.as_bytes()).unwrap()
    }

    /// The list read in the background is the list read in place; a listing no longer wanted
    /// stops at its next read.
    #[test]
    fn background_listing_equals_the_direct_one_and_stops_when_dropped() {
        let d = tempfile::tempdir().unwrap();
        let clip = d.path().join("c.mp4");
        let ok = Command::new("ffmpeg")
            .args(["-v", "error", "-f", "lavfi", "-i"])
            .arg("testsrc2=size=160x120:rate=25:duration=2")
            .args(["-c:v", "libx264", "-bf", "2", "-pix_fmt", "yuv420p"])
            .arg(&clip)
            .status()
            .unwrap();
        assert!(ok.success());
        let direct = list(&clip).unwrap();
        assert_eq!(direct.timestamps_s.len(), 50);
        assert_eq!(Listing::start(&clip).wait().unwrap(), direct);
        drop(Listing::start(&clip));

        let text = "packet|pts=0|dts=0|flags=K_\nstream|time_base=1/100|start_pts=0\n";
        let cancel = AtomicBool::new(false);
        let mut input = text.as_bytes();
        let mut reader = Cancellable {
            inner: &mut input,
            cancel: &cancel,
        };
        assert_eq!(parse(&clip, &mut reader).unwrap().timestamps_s, vec![0.0]);
        cancel.store(true, Ordering::Relaxed);
        let mut input = text.as_bytes();
        let mut reader = Cancellable {
            inner: &mut input,
            cancel: &cancel,
        };
        let e = parse(&clip, &mut reader).unwrap_err();
        assert!(e.to_string().contains("no longer wanted"), "{e}");
    }

    #[test]
    fn packets_sort_by_pts() {
        // Decode order with B-frames: I P B B I, presentation 0 3 1 2 4; side data is ignored.
        let t = times_of(
            "packet|pts=0|dts=-4|flags=K_|side_data|\npacket|pts=12|dts=0|flags=__\n\
             packet|pts=4|dts=4|flags=__\npacket|pts=8|dts=8|flags=__\n\
             packet|pts=16|dts=12|flags=K_\npacket|pts=N/A|dts=N/A|flags=__",
        );
        assert_eq!(t.timestamps_s, vec![0.0, 0.04, 0.08, 0.12, 0.16]);
        assert!(t.repeated.is_empty());
        // OpenCV: the pts, but the decode time for a pts of 0 (frame 0 gets packet 1's: 0).
        assert_eq!(t.opencv_s, vec![0.0, 0.04, 0.08, 0.12, 0.16]);
    }

    /// H.264's decoder holds frames back as deep as the stream declares even where a short clip
    /// reorders less: frame 0's OpenCV position is then the decode time of the packet that deep.
    /// Other codecs keep the list's own depth.
    #[test]
    fn h264s_declared_reorder_depth_places_frame_0() {
        let packets = "packet|pts=0|dts=-20|flags=K_\npacket|pts=30|dts=-10|flags=__\n\
                       packet|pts=10|dts=0|flags=__\npacket|pts=20|dts=10|flags=__";
        let with = |stream: &str| {
            let text = format!("{packets}\nstream|time_base=1/100|start_pts=0{stream}\n");
            parse(Path::new("v.mp4"), &mut text.as_bytes()).unwrap()
        };
        let h264 = with("|codec_name=h264|has_b_frames=2");
        assert_eq!(h264.opencv_s, vec![0.0, 0.1, 0.2, 0.3]);
        for other in ["", "|codec_name=mpeg4|has_b_frames=2", "|codec_name=h264"] {
            assert_eq!(with(other).opencv_s, vec![-0.1, 0.1, 0.2, 0.3], "{other}");
            assert_eq!(with(other).timestamps_s, h264.timestamps_s, "{other}");
        }
    }

    /// A repeated pts: FFmpeg's best effort moves to the decode times (which the muxer made
    /// increase); where those repeat too, the frame is placed a microsecond later.
    #[test]
    fn repeated_pts_follow_ffmpegs_best_effort() {
        let t = times_of(
            "packet|pts=0|dts=0|flags=K_\npacket|pts=1|dts=1|flags=__\n\
             packet|pts=1|dts=2|flags=__\npacket|pts=3|dts=3|flags=__",
        );
        assert_eq!(t.timestamps_s, vec![0.0, 0.01, 0.02, 0.03]);
        assert!(t.repeated.is_empty());
        let t = times_of(
            "packet|pts=0|dts=0|flags=K_\npacket|pts=1|dts=1|flags=__\n\
             packet|pts=1|dts=1|flags=__\npacket|pts=3|dts=3|flags=__",
        );
        assert_eq!(t.timestamps_s, vec![0.0, 0.01, 0.01 + REPEAT_STEP_S, 0.03]);
        assert_eq!(t.repeated, vec![2]);
    }

    /// A packet the edit list discards is no frame.
    #[test]
    fn discarded_packets_are_no_frames() {
        let t = times_of(
            "packet|pts=0|dts=0|flags=KD\npacket|pts=1|dts=1|flags=K_\npacket|pts=2|dts=2|flags=__",
        );
        assert_eq!(t.timestamps_s, vec![0.0, 0.01]);
    }

    #[test]
    fn packets_without_pts_use_their_dts() {
        // AVI: I and P packets have no pts, B packets have pts = dts.
        let t = times_of(
            "packet|pts=N/A|dts=0|flags=K_\npacket|pts=N/A|dts=1|flags=K_\n\
             packet|pts=N/A|dts=2|flags=__\npacket|pts=3|dts=3|flags=__\n\
             packet|pts=N/A|dts=4|flags=K_",
        );
        assert_eq!(t.timestamps_s, vec![0.0, 0.01, 0.02, 0.03, 0.04]);
    }

    #[test]
    fn malformed_lines_name_the_line() {
        let bad = "packet|pts=0|dts=0|flags=K_\npacket|pts=x|dts=0|flags=__\n";
        let e = parse(Path::new("v.mp4"), &mut bad.as_bytes()).unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
        let e = parse(
            Path::new("v.mp4"),
            &mut "stream|time_base=1/30\n".as_bytes(),
        )
        .unwrap_err();
        assert!(e.to_string().contains("start_pts"), "{e}");
        let e = parse(
            Path::new("v.mp4"),
            &mut "stream|time_base=1/30|start_pts=0\n".as_bytes(),
        );
        assert!(e.unwrap_err().to_string().contains("no video packets"));
    }

    #[test]
    fn pairing_compares_positions_from_frame_0() {
        let t = times_of("packet|pts=5|dts=5|flags=K_\npacket|pts=6|dts=6|flags=__");
        // OpenCV subtracts the stream's start (0 here): frame 1 at 0.06 s, frame 0 at 0.05 s.
        assert_eq!(t.pairs(1, 0.06, 0.05), Some(true));
        assert_eq!(t.pairs(1, 0.07, 0.05), Some(false));
        assert_eq!(t.pairs(1, 0.0, 0.05), None);
        assert_eq!(t.pairs(2, 0.07, 0.05), None);
    }
}

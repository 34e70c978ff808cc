//! Sliding windows over the frames of a long recording, and how their outputs are stitched.
//!
//! # Conventions
//! - Frames are indexed `0 … N−1` in increasing time; a window is a half-open range of frame
//!   indices `a..b` (`W = b − a` frames, the last frame of the window is `e = b − 1`).
//! - A continuous time `t` is placed on the frame axis by piecewise-linear interpolation of the
//!   frame times: `f(t) = k + (t − t_k) / (t_{k+1} − t_k)` between frames `k` and `k + 1`,
//!   clamped to `[0, N − 1]`, so non-uniform frame spacing is allowed.
//!
//! # Plan ([`plan_windows`])
//! Windows of `W` frames start every `S = W − O` frames (`O` the overlap); the last window is
//! moved back to end at the last frame, so every window has exactly `W` frames (the same
//! field shape, which makes warm starts a copy) and the last overlap may be larger than `O`.
//! `W = 0` or `W ≥ N` gives one window over all frames.
//!
//! # Stitching ([`blend`])
//! At frame position `f`:
//! - inside exactly one window: that window, weight 1;
//! - inside the overlap `[a', e]` of a window ending at `e` and the next one starting at `a'`:
//!   a linear cross-fade, the later window weighted `λ = (f − a') / (e − a')` (`λ = ½` when the
//!   overlap is a single frame and `f` is on it), the earlier `1 − λ`. The stitched series is
//!   therefore continuous in time, and a shared frame is the weighted mean of the two windows'
//!   reconstructions of it, each window dominating near its own centre;
//! - inside three or more windows (the last window moved back, or `O > W / 2`): the
//!   cross-fades nest, each window fading in over `[its start, the end of the covering window
//!   before it]` and taking that share from all the windows before it, so the weights stay
//!   continuous;
//! - in a gap between windows that do not overlap (per-frame static windows, `W = 1, O = 0`):
//!   linear interpolation between the earlier window at its last frame and the later window at
//!   its first frame — for static per-frame reconstructions this is exactly the linear
//!   interpolation of neighbouring frames;
//! - before the first / after the last frame: the first / last window at its end (no
//!   extrapolation in time).
//!
//! Each window is evaluated only at times inside its own frame range (the time is clamped).

use std::ops::Range;

/// The windows of `window` frames overlapping by `overlap` frames over `n_frames` frames (see
/// the module doc). Panics if `overlap ≥ window` while `window < n_frames` (a contract the
/// caller validates).
#[allow(clippy::single_range_in_vec_init)] // one window is a plan of one range
pub fn plan_windows(n_frames: usize, window: usize, overlap: usize) -> Vec<Range<usize>> {
    if n_frames == 0 {
        return Vec::new();
    }
    if window == 0 || window >= n_frames {
        return vec![0..n_frames];
    }
    assert!(overlap < window, "plan_windows: overlap {overlap} must be smaller than the window {window}");
    let stride = window - overlap;
    let mut out = Vec::new();
    let mut a = 0;
    loop {
        // Not `a + window >= n_frames`: for windows near the largest count the sum wrapped
        // around, and the plan grew without end.
        if a >= n_frames - window {
            out.push(n_frames - window..n_frames);
            break;
        }
        out.push(a..a + window);
        a += stride;
    }
    out.dedup();
    out
}

/// Position of time `t` on the frame axis (`times` increasing, non-empty), clamped.
pub fn frame_position(times: &[f64], t: f64) -> f64 {
    assert!(!times.is_empty(), "frame_position: no frames");
    // NaN reads as the first frame instead of indexing before it.
    if t.is_nan() || t <= times[0] || times.len() == 1 {
        return 0.0;
    }
    let last = times.len() - 1;
    if t >= times[last] {
        return last as f64;
    }
    let k = times.partition_point(|&x| x <= t) - 1;
    k as f64 + (t - times[k]) / (times[k + 1] - times[k])
}

/// Time at frame position `f` (inverse of [`frame_position`] inside the recording).
pub fn time_at(times: &[f64], f: f64) -> f64 {
    assert!(!times.is_empty(), "time_at: no frames");
    let last = times.len() - 1;
    let f = f.clamp(0.0, last as f64);
    let k = (f.floor() as usize).min(last);
    if k == last {
        return times[last];
    }
    times[k] + (f - k as f64) * (times[k + 1] - times[k])
}

/// The windows contributing at frame position `f`, as `(window index, weight, frame position
/// at which to evaluate it)`; weights sum to 1. `windows` as [`plan_windows`] returns them
/// (sorted, each starting after the previous one starts).
pub fn blend(windows: &[Range<usize>], f: f64) -> Vec<(usize, f64, f64)> {
    assert!(!windows.is_empty(), "blend: no windows");
    let first = (windows[0].start) as f64;
    let last_w = windows.len() - 1;
    let end = |w: &Range<usize>| (w.end - 1) as f64;
    if f <= first {
        return vec![(0, 1.0, first)];
    }
    if f >= end(&windows[last_w]) {
        return vec![(last_w, 1.0, end(&windows[last_w]))];
    }
    let inside: Vec<usize> =
        (0..windows.len()).filter(|&i| f >= windows[i].start as f64 && f <= end(&windows[i])).collect();
    match inside.as_slice() {
        [] => {
            // In a gap: the last window ending before f and the first starting after it.
            let k = (0..windows.len()).rev().find(|&i| end(&windows[i]) < f).unwrap_or(0);
            let next = (k + 1).min(last_w);
            let (e, a) = (end(&windows[k]), windows[next].start as f64);
            let lam = if a > e { (f - e) / (a - e) } else { 0.5 };
            vec![(k, 1.0 - lam, e), (next, lam, a)]
        }
        [i] => vec![(*i, 1.0, f)],
        [p, q] => {
            // Cross-fade between the two windows covering f.
            let lam = fade_in(windows, *p, *q, f);
            vec![(*p, 1.0 - lam, f), (*q, lam, f)]
        }
        many => {
            // Three or more windows cover f (the last window moved back to end at the last
            // frame, or an overlap above half the window): the cross-fades nest. Each window
            // fades in over [its start, the end of the covering window before it], taking
            // that share from all the windows before it, so every weight is continuous in f
            // (a window enters at 0 and has reached 0 when it leaves), and with two windows
            // this is the cross-fade above. Taking only the last two made the weights jump
            // where a third window began (by 4/3 at frame 13 for windows of 16 frames
            // overlapping by 4 over 29 frames).
            let mut out: Vec<(usize, f64, f64)> = Vec::with_capacity(many.len());
            for (k, &q) in many.iter().enumerate() {
                let lam = if k == 0 { 1.0 } else { fade_in(windows, many[k - 1], q, f) };
                out.iter_mut().for_each(|w| w.1 *= 1.0 - lam);
                out.push((q, lam, f));
            }
            out.retain(|w| w.1 > 0.0);
            out
        }
    }
}

/// The share of window `q` in the cross-fade with window `p` (the window before it that covers
/// frame position `f`) and those before: rising linearly from 0 at the start of `q` to 1 at
/// the end of `p` (½ where the two meet in a single frame).
fn fade_in(windows: &[Range<usize>], p: usize, q: usize, f: f64) -> f64 {
    let (a, e) = (windows[q].start as f64, (windows[p].end - 1) as f64);
    if e > a {
        ((f - a) / (e - a)).clamp(0.0, 1.0)
    } else {
        0.5
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[allow(clippy::single_range_in_vec_init)] // one-window plans
    fn plans_cover_every_frame_with_equal_windows() {
        assert_eq!(plan_windows(10, 4, 1), vec![0..4, 3..7, 6..10]);
        assert_eq!(plan_windows(9, 4, 2), vec![0..4, 2..6, 4..8, 5..9]);
        assert_eq!(plan_windows(3, 5, 1), [0..3]);
        assert_eq!(plan_windows(3, 0, 0), [0..3]);
        assert_eq!(plan_windows(3, 1, 0), vec![0..1, 1..2, 2..3]);
        for (n, w, o) in [(30, 8, 2), (301, 16, 4), (7, 3, 1)] {
            let p = plan_windows(n, w, o);
            assert!(p.iter().all(|r| r.len() == w));
            assert_eq!(p[0].start, 0);
            assert_eq!(p.last().map(|r| r.end), Some(n));
            assert!(p.windows(2).all(|x| x[1].start <= x[0].end && x[1].start > x[0].start));
        }
    }

    #[test]
    fn windows_near_the_largest_count_are_planned_without_overflow() {
        let n = usize::MAX;
        assert_eq!(plan_windows(n, n - 1, 1), vec![0..n - 1, 1..n]);
        assert_eq!(plan_windows(n, n - 2, 0), vec![0..n - 2, 2..n]);
    }

    #[test]
    fn weights_sum_to_one_and_are_continuous() {
        // The last two plans have frames that three windows cover: windows of 16 frames
        // overlapping by 4, the last moved back to end at frame 28 (frames 13–15 lie in three),
        // and an overlap above half the window.
        let plans = [
            plan_windows(10, 4, 2),
            plan_windows(10, 4, 1),
            plan_windows(5, 1, 0),
            plan_windows(29, 16, 4),
            plan_windows(12, 5, 4),
        ];
        for windows in &plans {
            let n = windows.last().map_or(0, |w| w.end);
            let mut prev: Option<Vec<f64>> = None;
            let mut f = -0.5;
            while f <= n as f64 {
                let b = blend(windows, f);
                let total: f64 = b.iter().map(|x| x.1).sum();
                assert!((total - 1.0).abs() < 1e-12);
                let mut dense = vec![0.0; windows.len()];
                for &(i, w, pos) in &b {
                    dense[i] += w;
                    assert!(pos >= windows[i].start as f64 - 1e-12 && pos <= (windows[i].end - 1) as f64 + 1e-12);
                }
                if let Some(p) = &prev {
                    // Small steps in f move the weights by at most a proportional amount,
                    // except across a single-frame overlap (a step by design).
                    let jump: f64 = p.iter().zip(&dense).map(|(a, b)| (a - b).abs()).sum();
                    let single_frame_overlap = windows.windows(2).any(|x| x[0].end - x[1].start == 1);
                    assert!(single_frame_overlap || jump < 0.05 + 1e-9, "jump {jump} at f = {f}");
                }
                prev = Some(dense);
                f += 0.01;
            }
        }
    }

    #[test]
    fn frame_positions_interpolate_non_uniform_times() {
        let t = [14.0, 15.0, 17.0];
        assert_eq!(frame_position(&t, 13.0), 0.0);
        assert!((frame_position(&t, 14.5) - 0.5).abs() < 1e-12);
        assert!((frame_position(&t, 16.0) - 1.5).abs() < 1e-12);
        assert_eq!(frame_position(&t, 18.0), 2.0);
        assert_eq!(frame_position(&t, f64::NAN), 0.0, "NaN reads as the first frame, not before it");
        for f in [0.0, 0.25, 1.0, 1.5, 2.0] {
            assert!((frame_position(&t, time_at(&t, f)) - f).abs() < 1e-12);
        }
    }

    #[test]
    fn gaps_interpolate_linearly_between_per_frame_windows() {
        let w = plan_windows(3, 1, 0);
        let b = blend(&w, 0.25);
        assert_eq!(b.len(), 2);
        assert_eq!((b[0].0, b[1].0), (0, 1));
        assert!((b[0].1 - 0.75).abs() < 1e-12 && (b[1].1 - 0.25).abs() < 1e-12);
        assert_eq!(blend(&w, 1.0), vec![(1, 1.0, 1.0)]);
    }

    /// Times at and beyond the first and last frames land on those frames; between frames the
    /// position and its inverse are linear in the frame's interval.
    #[test]
    fn frame_positions_and_times_clamp_at_the_recordings_ends() {
        let t = [14.0, 15.0, 17.0];
        assert_eq!(frame_position(&t, 14.0), 0.0);
        assert_eq!(frame_position(&t, 17.0), 2.0);
        assert_eq!(frame_position(&t, 15.0), 1.0);
        assert_eq!(frame_position(&[3.0], 7.0), 0.0, "one frame: every time is on it");
        assert_eq!(time_at(&t, -1.0), 14.0);
        assert_eq!(time_at(&t, 0.0), 14.0);
        assert_eq!(time_at(&t, 0.5), 14.5);
        assert_eq!(time_at(&t, 1.5), 16.0);
        assert_eq!(time_at(&t, 2.0), 17.0);
        assert_eq!(time_at(&t, 9.0), 17.0);
        assert_eq!(time_at(&[3.0], 0.5), 3.0);
    }

    /// Two windows sharing a single frame weigh it half and half; across a longer overlap the
    /// later window fades in linearly from its first frame to the earlier window's last.
    #[test]
    fn overlaps_cross_fade_linearly() {
        let w = plan_windows(7, 4, 1);
        assert_eq!(w, vec![0..4, 3..7]);
        assert_eq!(blend(&w, 3.0), vec![(0, 0.5, 3.0), (1, 0.5, 3.0)]);
        assert_eq!(blend(&w, 2.5), vec![(0, 1.0, 2.5)]);
        assert_eq!(blend(&w, 3.5), vec![(1, 1.0, 3.5)]);
        let w = plan_windows(10, 4, 2);
        assert_eq!(w, vec![0..4, 2..6, 4..8, 6..10]);
        // Windows 0..4 and 2..6 overlap on frames 2 and 3: the later one has λ = f − 2.
        for (f, lam) in [(2.0, 0.0), (2.25, 0.25), (2.5, 0.5), (3.0, 1.0)] {
            let b = blend(&w, f);
            assert_eq!(b.len(), 2, "{f}: {b:?}");
            assert_eq!((b[0].0, b[1].0), (0, 1));
            assert!((b[0].1 - (1.0 - lam)).abs() < 1e-12 && (b[1].1 - lam).abs() < 1e-12, "{f}: {b:?}");
            assert_eq!((b[0].2, b[1].2), (f, f));
        }
        // Before the first frame and after the last, the end windows at their ends.
        assert_eq!(blend(&w, -2.0), vec![(0, 1.0, 0.0)]);
        assert_eq!(blend(&w, 12.0), vec![(3, 1.0, 9.0)]);
    }

    /// Where three windows cover a frame the cross-fades nest: windows of 16 frames overlapping
    /// by 4 over 29 frames are 0..16, 12..28 and 13..29, and at frame 14 the second has faded in
    /// by 2/3 over the first, the third by 1/14 over both.
    #[test]
    fn three_covering_windows_nest_their_cross_fades() {
        let w = plan_windows(29, 16, 4);
        assert_eq!(w, vec![0..16, 12..28, 13..29]);
        let b = blend(&w, 14.0);
        let expect = [(0, (1.0 / 3.0) * (13.0 / 14.0)), (1, (2.0 / 3.0) * (13.0 / 14.0)), (2, 1.0 / 14.0)];
        assert_eq!(b.len(), 3, "{b:?}");
        for (got, want) in b.iter().zip(expect) {
            assert_eq!(got.0, want.0, "{b:?}");
            assert!((got.1 - want.1).abs() < 1e-12 && got.2 == 14.0, "{b:?}");
        }
        // At frame 13 the third window starts with weight 0 and is left out.
        let b = blend(&w, 13.0);
        assert_eq!(b.iter().map(|x| x.0).collect::<Vec<_>>(), vec![0, 1], "{b:?}");
        assert!((b[0].1 - 2.0 / 3.0).abs() < 1e-12 && (b[1].1 - 1.0 / 3.0).abs() < 1e-12, "{b:?}");
    }

    /// The shell loop of docs/cluster.md that sizes a Slurm job array counts the windows of
    /// this plan, and ends for every window, 0 (one window) included.
    #[test]
    #[cfg(unix)]
    fn the_cluster_guides_shell_count_matches_the_plan() {
        let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/cluster.md"))
            .expect("docs/cluster.md");
        let start = doc.find("N=0 a=0").expect("the count's first line");
        let end = start + doc[start..].find("; done").expect("the count's loop") + "; done".len();
        let count = &doc[start..end];
        for (frames, window, overlap) in
            [(120, 8, 2), (10, 4, 1), (9, 4, 2), (5, 5, 0), (5, 9, 3), (12, 0, 0), (7, 2, 1)]
        {
            let script = format!("F={frames} W={window} O={overlap}\n{count}\necho \"$N\"");
            let mut child = std::process::Command::new("sh")
                .args(["-c", &script])
                .stdout(std::process::Stdio::piped())
                .spawn()
                .expect("runs sh");
            let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
            while child.try_wait().expect("waits").is_none() {
                if std::time::Instant::now() > deadline {
                    child.kill().expect("kills sh");
                    child.wait().expect("reaps sh");
                    panic!("F={frames} W={window} O={overlap}: the loop never ends:\n{count}");
                }
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            let out = child.wait_with_output().expect("output");
            let n: usize = String::from_utf8_lossy(&out.stdout).trim().parse().expect("a count");
            assert_eq!(n, plan_windows(frames, window, overlap).len(), "F={frames} W={window} O={overlap}");
        }
    }
}

//! What the identification compares: a few periods of a few groups' readings, and the
//! residuals of candidates simulated against them.

use rayon::prelude::*;
use sts_dataset::Dataset;
use sts_twin_core::SERVO_RATE_HZ;

use super::candidate::Candidate;
use super::simulate::{discretise, simulate, Chunk, Discrete, LANES};

/// What the fit compares.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum Fit {
    Encoder,
    Tcp,
    Both,
}

/// Groups and samples the fit reads: in each of `groups`, every `stride`-th sample of a
/// window from the group's 1/12th on (the start's transient left out), the window lasting
/// `periods` of the command or `min_s`, whichever is longer, or to the group's end. In a
/// steady sine every period repeats the last, so a few of them carry what the whole group
/// does; the axis is simulated only to the window's end.
pub(super) struct Sample<'a> {
    dataset: &'a Dataset,
    pub(super) groups: Vec<usize>,
    stride: usize,
    /// Each of `groups`' first and end sample.
    windows: Vec<(usize, usize)>,
}

impl<'a> Sample<'a> {
    pub(super) fn new(dataset: &'a Dataset, group_step: usize, stride: usize, periods: f64, min_s: f64) -> Self {
        let groups: Vec<usize> = (0..dataset.groups.len()).step_by(group_step.max(1)).collect();
        let windows = groups
            .iter()
            .map(|&gi| {
                let len = dataset.groups[gi].len();
                let freq_hz = dataset.manifest.groups[gi].freq_hz;
                let window_s = if freq_hz > 0.0 { (periods / freq_hz).max(min_s) } else { f64::INFINITY };
                let first = len / 12;
                let end = (first as f64 + window_s * f64::from(SERVO_RATE_HZ)).min(len as f64) as usize;
                (first, end.max(first))
            })
            .collect();
        Sample { dataset, groups, stride, windows }
    }

    pub(super) fn residuals(&self, c: &Candidate, what: Fit) -> Vec<f64> {
        self.residuals_of(std::slice::from_ref(c), what).pop().unwrap_or_default()
    }

    /// [`Self::residuals`] of each candidate (all with the same command delay and effects),
    /// simulated [`LANES`] at a time, the groups in parallel.
    pub(super) fn residuals_of(&self, cs: &[Candidate], what: Fit) -> Vec<Vec<f64>> {
        let discrete: Vec<Discrete> = cs.iter().map(discretise).collect();
        let tasks: Vec<(usize, usize)> =
            (0..cs.len()).step_by(LANES).flat_map(|c0| (0..self.groups.len()).map(move |g| (c0, g))).collect();
        let parts: Vec<Vec<Vec<f64>>> = tasks
            .par_iter()
            .map(|&(c0, g)| {
                let c1 = (c0 + LANES).min(cs.len());
                self.group_residuals((&cs[c0..c1], &discrete[c0..c1]), g, what)
            })
            .collect();
        let mut out: Vec<Vec<f64>> = vec![Vec::new(); cs.len()];
        for (&(c0, _), part) in tasks.iter().zip(parts) {
            for (lane, r) in part.into_iter().enumerate() {
                out[c0 + lane].extend(r);
            }
        }
        out
    }

    /// The residuals of up to [`LANES`] candidates (with their linear parts) on the sample's
    /// `index`-th group.
    pub(super) fn group_residuals(&self, chunk: Chunk, index: usize, what: Fit) -> Vec<Vec<f64>> {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2 (checked just above).
                return unsafe { self.group_residuals_avx2(chunk, index, what) };
            }
        }
        self.group_residuals_generic(chunk, index, what)
    }

    /// [`Self::group_residuals`] compiled for AVX2 (4 lanes a vector instead of SSE2's 2; no
    /// FMA, and Rust never contracts `a * b + c`: the same bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn group_residuals_avx2(&self, chunk: Chunk, index: usize, what: Fit) -> Vec<Vec<f64>> {
        self.group_residuals_generic(chunk, index, what)
    }

    /// The body of [`Self::group_residuals`], for every instruction set.
    #[inline(always)]
    pub(super) fn group_residuals_generic(&self, chunk: Chunk, index: usize, what: Fit) -> Vec<Vec<f64>> {
        /// `N` lanes for the chunk's candidates, the last repeated in the lanes beyond them
        /// (whose residuals are dropped).
        #[inline(always)]
        fn lanes<const N: usize>(sample: &Sample, (cs, discrete): Chunk, index: usize, what: Fit) -> Vec<Vec<f64>> {
            let g = &sample.dataset.groups[sample.groups[index]];
            let (first, end) = sample.windows[index];
            let mut out = vec![Vec::new(); N];
            let mut next = first;
            let last = cs.len() - 1;
            simulate::<N>(
                std::array::from_fn(|l| &cs[l.min(last)]),
                std::array::from_fn(|l| &discrete[l.min(last)]),
                &g.z_cmd_um,
                first..end,
                |k, enc, tcp| {
                    if k != next {
                        return;
                    }
                    next += sample.stride;
                    for (l, r) in out.iter_mut().enumerate() {
                        if what != Fit::Tcp {
                            r.push(g.z_enc_um[k] - enc[l]);
                        }
                        if what != Fit::Encoder {
                            r.push(g.z_tcp_um[k] - tcp[l]);
                        }
                    }
                },
            );
            out.truncate(cs.len());
            out
        }
        match chunk.0.len() {
            1 => lanes::<1>(self, chunk, index, what),
            2 => lanes::<2>(self, chunk, index, what),
            3 | 4 => lanes::<4>(self, chunk, index, what),
            _ => lanes::<LANES>(self, chunk, index, what),
        }
    }
}

//! The study's outputs: `report.md` (a summary against the targets, then the
//! tables the README quotes), `results.json` (raw numbers) and `tradeoff.svg` (Q against
//! time over the t0 sweep, per scene and condition).

use super::corpus::Profile;
use super::judge::{Condition, SlowBecause, SweepPoint, Q_TARGET, TIME_TARGET};
use super::objects::{MIN_COVERAGE, MIN_TOLERANCE, REFERENCE_FACTOR};
use super::peer::PeerResult;
use super::truth::{self_error_share, TruthInfo, SELF_ERROR_SHARE, TRUTH_SPP_FACTOR};
use super::{median, BenchConfig, CorpusResult, SceneResult, Study, TargetCheck, TimeSplit};
use anyhow::Context;
use clap::ValueEnum as _;
use plotters::prelude::*;
use std::fmt::Write as _;

/// One scene's table, as Markdown.
#[must_use]
pub fn scene_table(r: &SceneResult) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "### {} ({}x{}, {} spp; reference {:.0} ms; FLIP noise floor {:.4})\n",
        r.scene, r.width, r.height, r.spp, r.reference_ms, r.noise_floor.mean
    );
    s.push_str(&methods_table(r));
    s.push('\n');
    s.push_str(&conditions_table(&r.conditions));
    s.push('\n');
    s.push_str(&denoised_table(&r.conditions));
    s.push_str("\nt0 sweep: ");
    for p in &r.sweep {
        let _ = write!(
            s,
            "{} ppd t0={} → {:.2}× time, {:.1}% px, FLIP {:.4}, Q {:.2}; ",
            p.ppd,
            p.t0,
            p.time_ratio,
            p.pixel_fraction * 100.0,
            p.flip,
            p.q
        );
    }
    s.push_str(&time_split_words(&r.time_split));
    s.push_str("\n\n| target | met | measured |\n|---|---|---|\n");
    for t in &r.targets {
        let _ = writeln!(
            s,
            "| {} | {} | {} |",
            t.target,
            if t.met { "yes" } else { "**no**" },
            t.detail
        );
    }
    s
}

/// One row per method of a scene.
fn methods_table(r: &SceneResult) -> String {
    let mut s = String::from("| method | time | × reference | pixels traced | spp | FLIP mean | FLIP p99 | FLIP vs converged | Glimpse metric (JND) | metric+triangulation |\n");
    s.push_str("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for m in &r.methods {
        let _ = writeln!(
            s,
            "| {} | {:.0} ms | {:.2} | {:.1}% | {} | {:.4} | {:.3} | {:.4} | {:.3} | {} |",
            m.method,
            m.ms,
            m.time_ratio,
            m.pixel_fraction * 100.0,
            m.spp.map_or("–".into(), |v| v.to_string()),
            m.flip.mean,
            m.flip.p99,
            m.converged_flip,
            m.glimpse_distance,
            m.overhead_share
                .map_or("–".into(), |v| format!("{:.1}%", v * 100.0)),
        );
    }
    s
}

/// The progressive run's time split, in two sentences.
fn time_split_words(ts: &TimeSplit) -> String {
    let mut s = String::new();
    let _ = write!(
        s,
        "\n\nTime split of the progressive run: tracing its pixels alone takes {:.2}× the \
         reference's time (one of them costs {:.2}× an average reference pixel); the loop's own \
         work (analysis, noise twins, vision model, metric, triangulation, shading) is the \
         other {:.2}×.",
        ts.traced_alone_ratio, ts.pixel_cost_ratio, ts.loop_ratio
    );
    let lp = &ts.loop_parts;
    // The in-loop trace and the alone trace are different runs: a difference below zero is
    // run-to-run noise, said as such rather than shown as a negative cost.
    let beyond = if lp.trace_beyond_alone_ms >= 0.0 {
        format!("{:.0} ms", lp.trace_beyond_alone_ms)
    } else {
        format!(
            "none measurable ({:.0} ms: run-to-run noise)",
            lp.trace_beyond_alone_ms
        )
    };
    let _ = write!(
        s,
        " In that run's statistics, the loop's part is: tracing beyond the pixels alone \
         {beyond} (noise twins, the mesh built beside the trace, batch tails), analysis {:.0} \
         ms, vision model and metric {:.0} ms, triangulation and shading {:.0} ms, the rest \
         {:.0} ms.",
        lp.analysis_ms, lp.metric_ms, lp.triangulate_ms, lp.other_ms
    );
    s
}

/// One row per condition: Q, time, the floor comparison, objects, the contact sheet.
#[must_use]
pub fn conditions_table(conditions: &[Condition]) -> String {
    let mut s = String::from(
        "| ppd | Q (FLIP vs truth: progressive / reference) | truth self-error (÷ reference's) \
         | × reference time | pixels traced \
         | Q ≤ 1 at ≤ 0.5× | vs noise floor | worst object (error / allowed) | contact sheet |\n\
         |---:|---:|---:|---:|---:|---|---:|---:|---|\n",
    );
    for c in conditions {
        let _ = writeln!(
            s,
            "| {} | {:.2} ({:.4} / {:.4}) | {} | {} | {:.1}% | {} | {:.2}× | {} | [sheet]({}) |",
            c.ppd,
            c.q,
            c.progressive_flip,
            c.reference_flip,
            self_cell(c),
            time_cell(c),
            c.pixel_fraction * 100.0,
            yes_no(c.passes()),
            c.floor_ratio,
            object_cell(c),
            c.sheet
        );
    }
    s
}

/// One row per condition: `adaptive` beside uniform + OIDN at its time and the reference
/// + OIDN, FLIP against the truth.
#[must_use]
pub fn denoised_table(conditions: &[Condition]) -> String {
    let mut s = String::from(
        "| ppd | adaptive: Q at × reference time (samples) | adaptive FLIP / uniform + OIDN \
         at equal time | uniform + OIDN: FLIP (spp, ms) | reference + OIDN FLIP | \
         Q ≤ 1 at ≤ 0.25× | ≤ 0.85× uniform + OIDN | worst object (error / allowed) | stop |\n\
         |---:|---:|---:|---:|---:|---|---|---:|---|\n",
    );
    for c in conditions {
        let Some(d) = &c.denoised else { continue };
        let _ = writeln!(
            s,
            "| {} | {:.2} at {:.2}× ({:.2}×) | {:.2} ({:.4} / {:.4}) | {:.4} ({}, {:.0}) | {:.4} | {} | {} | {:.2} {} | {} |",
            c.ppd,
            d.q,
            d.time_ratio,
            d.sample_ratio,
            d.vs_uniform_oidn,
            d.adaptive_flip,
            d.uniform_oidn_flip,
            d.uniform_oidn_flip,
            d.uniform_oidn_spp,
            d.uniform_oidn_ms,
            d.reference_oidn_flip,
            yes_no(d.fast_enough()),
            yes_no(d.beats_uniform()),
            d.worst_object_ratio,
            yes_no(d.objects_pass()),
            d.stop_reason
        );
    }
    s
}

/// The adaptive mode's targets over a set of conditions (`what` names the set).
fn denoised_targets(what: &str, conds: &[&Condition], share_needed: f64) -> Vec<TargetCheck> {
    let rows: Vec<&super::denoised::DenoisedRow> =
        conds.iter().filter_map(|c| c.denoised.as_ref()).collect();
    if rows.is_empty() {
        return Vec::new();
    }
    let count = |pass: &dyn Fn(&super::denoised::DenoisedRow) -> bool| {
        rows.iter().filter(|r| pass(r)).count()
    };
    let needed = |n: usize| n as f64 >= share_needed * rows.len() as f64;
    let beats = count(&super::denoised::DenoisedRow::beats_uniform);
    let objects = count(&super::denoised::DenoisedRow::objects_pass);
    let fast = count(&super::denoised::DenoisedRow::fast_enough);
    let mut times: Vec<f64> = rows.iter().map(|r| r.time_ratio).collect();
    let mut qs: Vec<f64> = rows.iter().map(|r| r.q).collect();
    let (time, q) = (median(&mut times), median(&mut qs));
    vec![
        TargetCheck {
            target: format!("{what}: adaptive FLIP ≤ 0.85× uniform + OIDN at equal time"),
            met: needed(beats),
            detail: count_with_share(beats, rows.len()),
        },
        TargetCheck {
            target: format!("{what}: adaptive Q ≤ 1 in ≤ 0.25× the reference's time"),
            met: needed(fast),
            detail: format!(
                "{}; median {time:.2}×, median Q {q:.2}",
                count_with_share(fast, rows.len())
            ),
        },
        TargetCheck {
            target: format!("{what}: adaptive keeps objects' colour"),
            met: objects == rows.len(),
            detail: count_with_share(objects, rows.len()),
        },
    ]
}

fn yes_no(b: bool) -> &'static str {
    if b {
        "yes"
    } else {
        "**no**"
    }
}

/// "0.42 (3 objects) yes", or "– (no object ≥ 0.5 %)".
fn object_cell(c: &Condition) -> String {
    if c.objects.is_empty() {
        return "– (no object ≥ 0.5 %)".into();
    }
    let worst = c
        .objects
        .iter()
        .max_by(|a, b| a.ratio().total_cmp(&b.ratio()))
        .expect("not empty");
    format!(
        "{:.2} (objects[{}]: {:.1}% / {:.1}%; {} judged) {}",
        c.worst_object_ratio,
        worst.object,
        worst.progressive_error * 100.0,
        worst.allowed * 100.0,
        c.objects.len(),
        yes_no(c.objects_pass())
    )
}

/// The truth's own error and its share of the reference's.
fn self_cell(c: &Condition) -> String {
    format!(
        "{:.4} ({:.2})",
        c.truth_self_flip,
        self_error_share(c.truth_self_flip, c.reference_flip)
    )
}

/// How converged a scene's truth is, in one sentence.
#[must_use]
pub fn truth_line(t: &TruthInfo) -> String {
    let capped = if t.capped {
        format!(
            "; **capped** at {:.0} s: its own error is above {SELF_ERROR_SHARE} of the \
             reference's at some condition",
            t.cap_s
        )
    } else {
        String::new()
    };
    format!("Truth: {} spp ({}× the scene's){capped}.", t.spp, t.factor)
}

/// `adaptive` against uniform + OIDN and the truth's own error, one row per scene and
/// condition, then the medians per condition.
#[must_use]
pub fn judged_table(results: &[CorpusResult]) -> String {
    let mut s = String::from(
        "| scene | size, spp | truth spp | ppd | reference FLIP | truth self-error (÷ reference's) \
         | adaptive Q at × time | adaptive ÷ uniform + OIDN | uniform + OIDN FLIP (spp) \
         | reference + OIDN FLIP | progressive Q at × time |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in results {
        for c in &r.conditions {
            let Some(d) = &c.denoised else { continue };
            let capped = if r.truth.capped { " (capped)" } else { "" };
            let _ = writeln!(
                s,
                "| {} | {}x{}, {} | {}{capped} | {} | {:.4} | {} | {:.2} at {:.2}× | {:.2} \
                 | {:.4} ({}) | {:.4} | {:.2} at {:.2}× |",
                r.scene,
                r.width,
                r.height,
                r.spp,
                r.truth.spp,
                c.ppd,
                c.reference_flip,
                self_cell(c),
                d.q,
                d.time_ratio,
                d.vs_uniform_oidn,
                d.uniform_oidn_flip,
                d.uniform_oidn_spp,
                d.reference_oidn_flip,
                c.q,
                c.time_ratio
            );
        }
    }
    s.push_str(&judged_medians(results));
    s
}

/// Per condition: the medians over the scenes of adaptive's Q, time ratio and ratio to
/// uniform + OIDN, and how many truths were within the rule.
fn judged_medians(results: &[CorpusResult]) -> String {
    let mut ppds: Vec<f32> = results
        .iter()
        .flat_map(|r| r.conditions.iter().map(|c| c.ppd))
        .collect();
    ppds.sort_by(f32::total_cmp);
    ppds.dedup();
    let mut s = String::from(
        "\n| ppd | scenes | median adaptive Q | median × time | median adaptive ÷ uniform + OIDN \
         | truths within the rule |\n|---:|---:|---:|---:|---:|---:|\n",
    );
    for ppd in ppds {
        let conds: Vec<&Condition> = results
            .iter()
            .flat_map(|r| r.conditions.iter().filter(|c| c.ppd == ppd))
            .collect();
        let rows: Vec<_> = conds.iter().filter_map(|c| c.denoised.as_ref()).collect();
        let mut q: Vec<f64> = rows.iter().map(|d| d.q).collect();
        let mut t: Vec<f64> = rows.iter().map(|d| d.time_ratio).collect();
        let mut v: Vec<f64> = rows.iter().map(|d| d.vs_uniform_oidn).collect();
        let within = conds
            .iter()
            .filter(|c| self_error_share(c.truth_self_flip, c.reference_flip) <= SELF_ERROR_SHARE)
            .count();
        let _ = writeln!(
            s,
            "| {ppd} | {} | {:.2} | {:.2} | {:.2} | {within} of {} |",
            rows.len(),
            median(&mut q),
            median(&mut t),
            median(&mut v),
            conds.len()
        );
    }
    s
}

/// One corpus scene, one line per condition (the progress log).
#[must_use]
pub fn corpus_line(r: &CorpusResult) -> String {
    r.conditions
        .iter()
        .map(|c| {
            format!(
                "  {} at {} ppd: Q {:.2}, {:.2}× time, {:.1}% px, objects {:.2} {}; \
                 adaptive Q {:.2} at {:.2}×, ÷ uniform + OIDN {:.2}; truth self {}",
                r.scene,
                c.ppd,
                c.q,
                c.time_ratio,
                c.pixel_fraction * 100.0,
                c.worst_object_ratio,
                if c.passes() { "pass" } else { "FAIL" },
                c.denoised.as_ref().map_or(f64::NAN, |d| d.q),
                c.denoised.as_ref().map_or(f64::NAN, |d| d.time_ratio),
                c.denoised.as_ref().map_or(f64::NAN, |d| d.vs_uniform_oidn),
                self_cell(c)
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// The corpus, one row per scene and condition.
fn corpus_table(corpus: &[CorpusResult]) -> String {
    let mut s = String::from(
        "| scene | size, spp | exposure | ppd | Q | × reference time | pixels traced | Q ≤ 1 at ≤ 0.5× \
         | vs noise floor | worst object | contact sheet |\n\
         |---|---|---:|---:|---:|---:|---:|---|---:|---:|---|\n",
    );
    for r in corpus {
        for c in &r.conditions {
            let declared = if c.ppd == r.declared_ppd {
                " (declared)"
            } else {
                ""
            };
            let _ = writeln!(
                s,
                "| [{}]({}) | {}x{}, {} | {} | {}{declared} | {:.2} | {} | {:.1}% | {} | {:.2}× | {} | [sheet]({}) |",
                r.scene,
                r.file,
                r.width,
                r.height,
                r.spp,
                r.exposure,
                c.ppd,
                c.q,
                time_cell(c),
                c.pixel_fraction * 100.0,
                yes_no(c.passes()),
                c.floor_ratio,
                object_cell(c),
                c.sheet
            );
        }
    }
    s
}

/// The time ratio as the traced pixels' share + the rest, and why it missed the target.
fn time_cell(c: &Condition) -> String {
    let why = match c.slow_because() {
        None => "",
        Some(SlowBecause::Overhead) => ", overhead-bound",
        Some(SlowBecause::Pixels) => ", pixel-bound",
        Some(SlowBecause::CheapPaths) => ", traced whole: paths too cheap for the loop",
    };
    format!(
        "{:.2} ({:.2} + {:.2}{why})",
        c.time_ratio,
        c.pixel_fraction,
        c.overhead_ratio()
    )
}

/// A t0 sweep is "monotone" when, as t0 grows, the time never rises by more than
/// [`SWEEP_TIME_SLACK`] (one run per point: timing noise) and Q never falls by more than
/// [`SWEEP_Q_SLACK`].
pub const SWEEP_TIME_SLACK: f64 = 0.02;
pub const SWEEP_Q_SLACK: f64 = 0.01;
/// The sweep's ends: a cheap preview at ≤ 0.3× the time, and Q ≤ 0.9.
const SWEEP_PREVIEW_TIME: f64 = 0.3;
const SWEEP_BEST_Q: f64 = 0.9;

/// One scene's sweep at one condition, checked.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SweepCheck {
    pub scene: String,
    pub ppd: f32,
    pub monotone: bool,
    pub cheapest_time: f64,
    pub best_q: f64,
}

impl SweepCheck {
    #[must_use]
    pub fn met(&self) -> bool {
        self.monotone && self.cheapest_time <= SWEEP_PREVIEW_TIME && self.best_q <= SWEEP_BEST_Q
    }
}

/// The sweep of `points` (one scene, one ppd) checked; points in any order.
#[must_use]
pub fn sweep_check(scene: &str, ppd: f32, points: &[&SweepPoint]) -> SweepCheck {
    let mut p = points.to_vec();
    p.sort_by(|a, b| a.t0.total_cmp(&b.t0));
    let monotone = p.windows(2).all(|w| {
        w[1].time_ratio <= w[0].time_ratio + SWEEP_TIME_SLACK && w[1].q >= w[0].q - SWEEP_Q_SLACK
    });
    SweepCheck {
        scene: scene.into(),
        ppd,
        monotone,
        cheapest_time: p.iter().map(|s| s.time_ratio).fold(f64::INFINITY, f64::min),
        best_q: p.iter().map(|s| s.q).fold(f64::INFINITY, f64::min),
    }
}

/// Every bundled scene's sweep (the one `of` picks), per condition.
fn sweep_checks(scenes: &[SceneResult], of: Sweep) -> Vec<SweepCheck> {
    let mut out = Vec::new();
    for r in scenes {
        let points = of(r);
        let mut ppds: Vec<f32> = points.iter().map(|p| p.ppd).collect();
        ppds.dedup();
        for ppd in ppds {
            let pts: Vec<&SweepPoint> = points.iter().filter(|p| p.ppd == ppd).collect();
            out.push(sweep_check(&r.scene, ppd, &pts));
        }
    }
    out
}

/// Which of a scene's sweeps: the progressive loop's or the adaptive mode's.
type Sweep = fn(&SceneResult) -> &[SweepPoint];

fn progressive_sweep(r: &SceneResult) -> &[SweepPoint] {
    &r.sweep
}

fn adaptive_sweep(r: &SceneResult) -> &[SweepPoint] {
    &r.adaptive_sweep
}

/// How many of `conds` pass `pass`.
fn share(conds: &[&Condition], pass: impl Fn(&Condition) -> bool) -> (usize, usize) {
    (conds.iter().filter(|c| pass(c)).count(), conds.len())
}

/// "n of m", with the misses named when there are any.
fn count_with_misses(n: usize, of: usize, misses: &[String]) -> String {
    if misses.is_empty() {
        format!("{n} of {of}")
    } else {
        format!("{n} of {of}; missed: {}", misses.join(", "))
    }
}

/// "n of m (p %)", or "none judged" for an empty set (never NaN %).
fn count_with_share(n: usize, of: usize) -> String {
    if of == 0 {
        "none judged".into()
    } else {
        format!("{n} of {of} ({:.0} %)", 100.0 * n as f64 / of as f64)
    }
}

fn q_time_target(what: &str) -> String {
    format!("{what}: Q ≤ {Q_TARGET} at ≤ {TIME_TARGET}× time")
}

/// The study's targets over every scene, checked on this run's numbers.
#[must_use]
pub fn summary(study: &Study) -> Vec<TargetCheck> {
    let mut t = bundled_targets(&study.scenes);
    if !study.corpus.is_empty() {
        t.extend(corpus_targets(&study.corpus));
    }
    t.extend(sweep_target(
        &study.scenes,
        progressive_sweep,
        "progressive",
    ));
    t.extend(sweep_target(&study.scenes, adaptive_sweep, "adaptive"));
    t
}

/// Every bundled scene passes at each condition; objects keep their colour.
fn bundled_targets(scenes: &[SceneResult]) -> Vec<TargetCheck> {
    let all: Vec<(&SceneResult, &Condition)> = scenes
        .iter()
        .flat_map(|r| r.conditions.iter().map(move |c| (r, c)))
        .collect();
    let mut ppds: Vec<f32> = all.iter().map(|(_, c)| c.ppd).collect();
    ppds.sort_by(f32::total_cmp);
    ppds.dedup();
    let mut t: Vec<TargetCheck> = ppds
        .iter()
        .map(|&ppd| {
            let at: Vec<_> = all.iter().filter(|(_, c)| c.ppd == ppd).collect();
            let misses: Vec<String> = at
                .iter()
                .filter(|(_, c)| !c.passes())
                .map(|(r, c)| format!("{} Q {:.2} at {:.2}×", r.scene, c.q, c.time_ratio))
                .collect();
            TargetCheck {
                target: q_time_target(&format!("bundled scenes at {ppd} ppd")),
                met: misses.is_empty(),
                detail: count_with_misses(at.len() - misses.len(), at.len(), &misses),
            }
        })
        .collect();
    if !all.is_empty() {
        let misses: Vec<String> = all
            .iter()
            .filter(|(_, c)| !c.objects_pass())
            .map(|(r, c)| format!("{} at {} ppd ({:.2})", r.scene, c.ppd, c.worst_object_ratio))
            .collect();
        t.push(TargetCheck {
            target: "bundled scenes: objects keep their colour (every scene and condition)".into(),
            met: misses.is_empty(),
            detail: count_with_misses(all.len() - misses.len(), all.len(), &misses),
        });
    }
    let conds: Vec<&Condition> = all.iter().map(|(_, c)| *c).collect();
    t.extend(denoised_targets("bundled scenes", &conds, 1.0));
    t
}

/// ≥ 90 % of the corpus passes at its declared ppd (and at each standard condition it
/// was judged at); the median time; objects keep their colour.
fn corpus_targets(corpus: &[CorpusResult]) -> Vec<TargetCheck> {
    let declared: Vec<&Condition> = corpus.iter().map(|r| &r.conditions[0]).collect();
    let mut at_ppd = vec![("each scene's declared ppd".to_string(), declared.clone())];
    let mut ppds: Vec<f32> = corpus
        .iter()
        .flat_map(|r| r.conditions.iter().skip(1).map(|c| c.ppd))
        .collect();
    ppds.sort_by(f32::total_cmp);
    ppds.dedup();
    for ppd in ppds {
        // A scene declared at this ppd is judged there once (its declared condition).
        let at = corpus
            .iter()
            .filter_map(|r| r.conditions.iter().find(|c| c.ppd == ppd))
            .collect();
        at_ppd.push((format!("{ppd} ppd"), at));
    }
    let mut t: Vec<TargetCheck> = at_ppd
        .into_iter()
        .map(|(label, at)| {
            let (n, of) = share(&at, Condition::passes);
            TargetCheck {
                target: q_time_target(&format!("corpus at {label}, ≥ 90 % of scenes")),
                met: of > 0 && n as f64 >= 0.9 * of as f64,
                detail: count_with_share(n, of),
            }
        })
        .collect();
    let mut times: Vec<f64> = declared.iter().map(|c| c.time_ratio).collect();
    let med = median(&mut times);
    t.push(TargetCheck {
        target: "median corpus time (declared ppd) ≤ 0.35× the reference".into(),
        met: med <= 0.35,
        detail: format!("{med:.2}×"),
    });
    let all: Vec<&Condition> = corpus.iter().flat_map(|r| &r.conditions).collect();
    t.extend(denoised_targets("corpus, ≥ 90 % of conditions", &all, 0.9));
    let (n, of) = share(&all, Condition::objects_pass);
    t.push(TargetCheck {
        target: "corpus: objects keep their colour (every scene and condition)".into(),
        met: n == of,
        detail: count_with_share(n, of),
    });
    t
}

/// Every bundled scene's t0 sweep is monotone and spans a cheap preview to Q ≤ 0.9.
fn sweep_target(scenes: &[SceneResult], of: Sweep, what: &str) -> Option<TargetCheck> {
    let sweeps = sweep_checks(scenes, of);
    if sweeps.is_empty() {
        return None;
    }
    let misses: Vec<String> = sweeps
        .iter()
        .filter(|s| !s.met())
        .map(|s| {
            format!(
                "{} {} ppd ({}, cheapest {:.2}×, best Q {:.2})",
                s.scene,
                s.ppd,
                if s.monotone {
                    "monotone"
                } else {
                    "not monotone"
                },
                s.cheapest_time,
                s.best_q
            )
        })
        .collect();
    Some(TargetCheck {
        target: format!(
            "{what} t0 sweep monotone, from ≤ {SWEEP_PREVIEW_TIME}× time to Q ≤ {SWEEP_BEST_Q}"
        ),
        met: misses.is_empty(),
        detail: format!(
            "{} scene/ppd sweeps",
            count_with_misses(sweeps.len() - misses.len(), sweeps.len(), &misses)
        ),
    })
}

/// The command line's flags that shaped this run, as typed.
fn flags(cfg: &BenchConfig) -> String {
    let mut f = String::new();
    if cfg.quick {
        f.push_str(" --quick");
    }
    if cfg.spp_factor != 1 {
        let _ = write!(f, " --spp-factor {}", cfg.spp_factor);
    }
    let defaults: &[f32] = if cfg.quick {
        &super::QUICK_CONDITIONS
    } else {
        &super::STANDARD_CONDITIONS
    };
    if cfg.conditions != defaults {
        let list: Vec<String> = cfg.conditions.iter().map(f32::to_string).collect();
        let _ = write!(f, " --ppd {}", list.join(","));
    }
    if let Some(c) = &cfg.corpus {
        let _ = write!(f, " --corpus {} --seed {}", c.scenes, c.seed);
        if c.at_conditions {
            f.push_str(" --corpus-at-conditions");
        }
    }
    if let Some(c) = cfg.corpus.as_ref().filter(|c| c.profile != Profile::Small) {
        let name = c
            .profile
            .to_possible_value()
            .map(|v| v.get_name().to_owned());
        let _ = write!(f, " --corpus-profile {}", name.unwrap_or_default());
    }
    if !cfg.bundled {
        f.push_str(" --corpus-only");
    }
    if let Some(side) = cfg.min_side {
        let _ = write!(f, " --min-side {side}");
    }
    if let Some(dir) = &cfg.public_dir {
        let _ = write!(f, " --public {}", dir.display());
    }
    if cfg.judge_only {
        f.push_str(" --judge-only");
    }
    let default_runs = if cfg.quick { 1 } else { super::TIMING_RUNS };
    if cfg.runs != default_runs {
        let _ = write!(f, " --runs {}", cfg.runs);
    }
    let default_cap = if cfg.quick {
        super::QUICK_TRUTH_CAP_S
    } else {
        super::TRUTH_CAP_S
    };
    if cfg.truth_cap_s != default_cap {
        let _ = write!(f, " --truth-cap {}", cfg.truth_cap_s);
    }
    f
}

/// Writes report.md, results.json and tradeoff.svg into the output folder.
pub fn write(
    cfg: &BenchConfig,
    study: &Study,
    peer: &Result<PeerResult, String>,
) -> anyhow::Result<()> {
    let targets = summary(study);
    let md = markdown(cfg, study, peer, &targets);
    let p = cfg.out_dir.join("report.md");
    std::fs::write(&p, &md).with_context(|| format!("cannot write {}", p.display()))?;
    let json = serde_json::json!({
        "summary": targets,
        "sweep_checks": sweep_checks(&study.scenes, progressive_sweep),
        "adaptive_sweep_checks": sweep_checks(&study.scenes, adaptive_sweep),
        "scenes": study.scenes,
        "judged": study.judged,
        "corpus": study.corpus,
        "peer": peer.as_ref().ok(),
        "peer_error": peer.as_ref().err(),
    });
    let p = cfg.out_dir.join("results.json");
    std::fs::write(&p, serde_json::to_vec_pretty(&json)?)
        .with_context(|| format!("cannot write {}", p.display()))?;
    // A corpus-only run has no t0 sweep to draw.
    if !study.scenes.is_empty() {
        plot(cfg, &study.scenes)?;
    }
    println!("{md}");
    Ok(())
}

/// `report.md`: the summary, the bundled scenes against the truth, the corpus, every
/// method per scene, the peer, then how it is judged.
fn markdown(
    cfg: &BenchConfig,
    study: &Study,
    peer: &Result<PeerResult, String>,
    targets: &[TargetCheck],
) -> String {
    let mut md = String::from("# Glimpse speed-versus-accuracy study\n\n");
    let _ = writeln!(
        md,
        "Generated by `glimpse bench{}`.\n\n## Summary against the targets\n\n{}\n",
        flags(cfg),
        in_short(study)
    );
    md.push_str("| target | met | measured |\n|---|---|---|\n");
    for t in targets {
        let _ = writeln!(md, "| {} | {} | {} |", t.target, yes_no(t.met), t.detail);
    }
    md.push_str(WORDS);
    md.push('\n');
    if !study.scenes.is_empty() {
        md.push_str("## Bundled scenes against the truth\n\n");
        for r in &study.scenes {
            let _ = writeln!(
                md,
                "### {}\n\n{}\n\n{}\n{}",
                r.scene,
                truth_line(&r.truth),
                conditions_table(&r.conditions),
                denoised_table(&r.conditions)
            );
        }
        md.push_str(&sweep_section(study));
    }
    if !study.judged.is_empty() {
        let _ = writeln!(
            md,
            "## Scenes judged at the conditions ({} scenes)\n\n{}\n{}",
            study.judged.len(),
            corpus_table(&study.judged),
            judged_table(&study.judged)
        );
    }
    if !study.corpus.is_empty() {
        let _ = writeln!(
            md,
            "## Corpus ({} generated scenes; documents in `corpus/`)\n\n{}\n{}",
            study.corpus.len(),
            corpus_table(&study.corpus),
            judged_table(&study.corpus)
        );
    }
    if !study.scenes.is_empty() {
        md.push_str(&every_method_section(cfg, study));
    }
    if cfg.bundled {
        md.push_str(&peer_section(peer));
    }
    md.push_str(&how_judged(cfg));
    md
}

/// Every method on every bundled scene, with what the columns mean.
fn every_method_section(cfg: &BenchConfig, study: &Study) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "## Bundled scenes: every method\n\nAll images of a scene are judged by LDR-FLIP \
         (nv-flip, at the scene's pixels per degree, display-referred) against an \
         independent reference (same scene and spp, another seed); the reference row's \
         FLIP is that noise floor. Guo stops at the progressive run's ray count (noise \
         twins included); uniform gets the progressive run's wall time. \"FLIP vs \
         converged\" judges the same images against the truth (at least {TRUTH_SPP_FACTOR}× the \
         samples, other seeds). The reference and progressive times are medians of 3 \
         alternating runs (one run in `--quick`); every other cell is one render. All in \
         one run on this machine: the ratios measured side by side are the result, not \
         the absolute times.\n"
    );
    if cfg.spp_factor != 1 {
        let _ = writeln!(
            md,
            "Run with `--spp-factor {}`: every scene's samples per pixel are {}× those written \
             in its file (the spp column shows the samples used).\n",
            cfg.spp_factor, cfg.spp_factor
        );
    }
    for r in &study.scenes {
        md.push_str(&scene_table(r));
        md.push('\n');
    }
    md
}

/// The closing section: what the truth is, Q, the times, the objects test, the sheets.
fn how_judged(cfg: &BenchConfig) -> String {
    let mut judge = String::new();
    let _ = writeln!(
        judge,
        "\n## How it is judged, exactly\n\nTruth = the mean of two halves, each the scene \
         traced with {}× its samples per pixel and other seeds (cached in `{}`); FLIP between \
         the halves is the truth's own error (\"truth self\"), and where it is above \
         {SELF_ERROR_SHARE} × FLIP(reference, truth) at a condition, the truth is given twice \
         the samples, until it is not or its estimated time would pass {:.0} s (then \
         \"capped\"). At each declared viewing condition (the \
         scene's `display.pixels_per_degree` set to that value for the progressive render and \
         for FLIP), Q = FLIP(progressive, truth) / FLIP(reference, truth): Q ≤ 1 means the \
         progressive picture is at least as close to the truth as the reference. Times are \
         medians of {} alternating reference/progressive runs per condition. \"vs noise floor\" \
         is the older comparison: FLIP(progressive, independent reference) over FLIP(reference, \
         independent reference). **Objects keep their colour**: over every object covering ≥ \
         {:.1} % of the image (object-id map), the progressive image's mean linear radiance must \
         be within max({:.0} %, {REFERENCE_FACTOR}× the reference's own error) of the truth's, \
         the error luminance-weighted (Σ w_c |p_c − t_c| / Σ w_c t_c, Rec.709 weights); the \
         column shows the worst object's error over its allowance (≤ 1 passes). Each contact \
         sheet shows reference | progressive | truth | FLIP map of progressive vs truth \
         (magma: black none, yellow most). The t0 sweep is monotone when, as t0 grows, time \
         never rises by more than {SWEEP_TIME_SLACK}× and Q never falls by more than \
         {SWEEP_Q_SLACK} (one run per point).\n",
        TRUTH_SPP_FACTOR / 2,
        cfg.cache_dir.display(),
        cfg.truth_cap_s,
        cfg.runs,
        MIN_COVERAGE * 100.0,
        MIN_TOLERANCE * 100.0,
    );
    judge
}

/// The words the tables use, in plain terms, right after the summary.
const WORDS: &str = "\nWords used below: **the reference** is the ordinary render, every pixel \
traced with the scene's samples; **the truth** is a render with many more samples, as close \
to noise-free as we can afford; **Q** is how far the progressive picture is from the truth \
divided by how far the reference is (by FLIP, a measure of visible difference): below 1 the \
progressive picture is at least as close to the truth as the reference; **× reference time** \
is the progressive render's time over the reference's (0.5× is twice as fast), split in \
brackets into the traced pixels' share (what they cost the reference) + the rest (the \
analysis's primary rays, the noise twins and the loop's own whole-image work: triangulation, \
reconstruction, shading, the vision model); a render slower than 0.5× is \
**overhead-bound** when the rest is the larger part (the scene's pixels are too cheap for \
skipping most of them to pay for it) and **pixel-bound** otherwise; **ppd** \
(pixels per degree) is how far away the picture is seen: higher is farther, where small \
errors are harder to see; **t0** is the knob that trades time for accuracy (a larger t0 \
stops refining sooner). For both Q and time, lower is better.\n";

/// One sentence on the bundled scenes (and one on the corpus) before the targets table.
fn in_short(study: &Study) -> String {
    let sentence = |what: &str, conds: &[&Condition]| {
        let (n, of) = share(conds, Condition::passes);
        let mut times: Vec<f64> = conds.iter().map(|c| c.time_ratio).collect();
        let mut qs: Vec<f64> = conds.iter().map(|c| c.q).collect();
        let slow = |why| {
            conds
                .iter()
                .filter(|c| c.slow_because() == Some(why))
                .count()
        };
        format!(
            "on {n} of {of} {what} the progressive picture was at least as close to the truth \
             as the reference, in at most {TIME_TARGET}× its time (median {:.2}× the \
             reference's time, median Q {:.2}; of those slower than {TIME_TARGET}×, {} were \
             overhead-bound, {} pixel-bound and {} traced whole because their paths were \
             too cheap for the loop)",
            median(&mut times),
            median(&mut qs),
            slow(SlowBecause::Overhead),
            slow(SlowBecause::Pixels),
            slow(SlowBecause::CheapPaths),
        )
    };
    let mut parts = Vec::new();
    let bundled: Vec<&Condition> = study.scenes.iter().flat_map(|r| &r.conditions).collect();
    if !bundled.is_empty() {
        parts.push(sentence(
            "bundled scene and viewing-distance pairs",
            &bundled,
        ));
    }
    let corpus: Vec<&Condition> = study.corpus.iter().map(|r| &r.conditions[0]).collect();
    if !corpus.is_empty() {
        parts.push(sentence(
            "generated scenes (at their own viewing distance)",
            &corpus,
        ));
    }
    if parts.is_empty() {
        return "In short: nothing was judged.".into();
    }
    format!(
        "In short: {}. The table says which of the targets this run met.",
        parts.join("; ")
    )
}

/// The t0 sweep as a table: one row per scene and condition, one cell per t0.
fn sweep_section(study: &Study) -> String {
    let mut s = String::from(
        "## The knob: t0 sweep (time × reference, Q)\n\nOne progressive run per point; \
         `tradeoff.svg` plots Q against time per scene and condition (lower-left is better).\n\n",
    );
    s.push_str(&sweep_table(study, progressive_sweep));
    s.push_str("\nThe same sweep in adaptive mode (denoised), one run per point:\n\n");
    s.push_str(&sweep_table(study, adaptive_sweep));
    s
}

/// One row per scene and condition of the sweep `of` picks, one column per t0.
fn sweep_table(study: &Study, of: Sweep) -> String {
    let mut t0s: Vec<f32> = study
        .scenes
        .iter()
        .flat_map(|r| of(r).iter().map(|p| p.t0))
        .collect();
    t0s.sort_by(f32::total_cmp);
    t0s.dedup();
    let mut s = String::from("| scene | ppd |");
    for t0 in &t0s {
        let _ = write!(s, " t0 = {t0} |");
    }
    s.push_str(" monotone, ≤ 0.3× to Q ≤ 0.9 |\n|---|---:|");
    s.push_str(&"---:|".repeat(t0s.len()));
    s.push_str("---|\n");
    for c in &sweep_checks(&study.scenes, of) {
        let r = study
            .scenes
            .iter()
            .find(|r| r.scene == c.scene)
            .expect("checks come from these scenes");
        let _ = write!(s, "| {} | {} |", c.scene, c.ppd);
        for t0 in &t0s {
            match of(r).iter().find(|p| p.ppd == c.ppd && p.t0 == *t0) {
                Some(p) => {
                    let _ = write!(s, " {:.2}×, Q {:.2} |", p.time_ratio, p.q);
                }
                None => s.push_str(" – |"),
            }
        }
        let shape = if c.monotone {
            "monotone"
        } else {
            "not monotone"
        };
        let _ = writeln!(s, " {} ({shape}) |", yes_no(c.met()));
    }
    s
}

fn peer_section(peer: &Result<PeerResult, String>) -> String {
    let mut md = String::from("## Peer: Mitsuba 3 at equal time (Cornell box)\n\n");
    match peer {
        Ok(p) => {
            let _ = writeln!(
                md,
                "| renderer | time | spp | FLIP vs own converged render (spp) |\n|---|---:|---:|---:|\n\
                 | Glimpse progressive | {:.0} ms | – | {:.4} ({}) |\n| Mitsuba 3 `{}` | {:.0} ms | {} | {:.4} ({}) |\n",
                p.glimpse_ms, p.glimpse_flip.mean, p.glimpse_converged_spp, p.mitsuba_variant, p.mitsuba_ms,
                p.mitsuba_spp, p.mitsuba_flip.mean, p.mitsuba_converged_spp
            );
        }
        Err(why) => {
            let _ = writeln!(md, "{}\n", peer_not_run(why));
        }
    }
    md
}

/// Why the peer did not run, in one sentence. A script's own error output does not belong
/// in the report: it is kept whole in results.json's `peer_error`, and the report says so.
fn peer_not_run(why: &str) -> String {
    let ours = !why.starts_with("mitsuba script") && !why.starts_with("cannot run");
    let first = why.lines().next().unwrap_or("").trim();
    if ours && first.chars().count() <= 120 && why.trim() == first {
        format!("Not run: {}.", first.trim_end_matches('.'))
    } else {
        "Not run: the Mitsuba 3 script did not complete (its error is in results.json, \
         `peer_error`)."
            .into()
    }
}

/// Q against time (× reference) over each scene's t0 sweep, one line per scene and
/// condition: lower-left is better.
fn plot(cfg: &BenchConfig, results: &[SceneResult]) -> anyhow::Result<()> {
    let p = cfg.out_dir.join("tradeoff.svg");
    let root = SVGBackend::new(&p, (900, 560)).into_drawing_area();
    root.fill(&WHITE)?;
    let points = || results.iter().flat_map(|r| r.sweep.iter());
    let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
    let max_q = points().map(|s| finite(s.q)).fold(1.2f64, f64::max) * 1.05;
    let max_t = points()
        .map(|s| finite(s.time_ratio))
        .fold(1.0f64, f64::max)
        * 1.05;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "t0 sweep: Q against time (lower-left is better)",
            ("sans-serif", 20),
        )
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..max_t, 0f64..max_q)?;
    chart
        .configure_mesh()
        .x_desc("time as a share of the reference's time (lower: faster)")
        .y_desc("Q: error vs truth over the reference's (lower: closer)")
        .draw()?;
    // The targets: Q = 1 and 0.5× time, named in the legend (the corner they bound,
    // lower-left of both, is where a method meets them).
    let grey = BLACK.mix(0.4);
    chart
        .draw_series(LineSeries::new(
            [(0.0, Q_TARGET), (max_t, Q_TARGET)],
            grey.stroke_width(1),
        ))?
        .label(format!(
            "Q = {Q_TARGET}: the reference's own noise (target: at or below)"
        ))
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey));
    chart
        .draw_series(LineSeries::new(
            [(TIME_TARGET, 0.0), (TIME_TARGET, max_q)],
            grey.stroke_width(1),
        ))?
        .label(format!(
            "{TIME_TARGET}× the reference's time (target: at or left of it)"
        ))
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey));
    let mut series = 0;
    for r in results {
        let mut ppds: Vec<f32> = r.sweep.iter().map(|s| s.ppd).collect();
        ppds.dedup();
        for ppd in ppds {
            let c = Palette99::pick(series).to_rgba();
            series += 1;
            let mut pts: Vec<&SweepPoint> = r.sweep.iter().filter(|s| s.ppd == ppd).collect();
            pts.sort_by(|a, b| a.t0.total_cmp(&b.t0));
            let xy: Vec<(f64, f64)> = pts
                .iter()
                .map(|s| (finite(s.time_ratio), finite(s.q)))
                .collect();
            chart
                .draw_series(LineSeries::new(xy.clone(), c.stroke_width(2)))?
                .label(format!("{} @ {ppd} ppd", r.scene))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c));
            chart.draw_series(xy.iter().map(|&(x, y)| Circle::new((x, y), 3, c.filled())))?;
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(t0: f32, time_ratio: f64, q: f64) -> SweepPoint {
        SweepPoint {
            ppd: 60.0,
            t0,
            time_ratio,
            pixel_fraction: 0.2,
            flip: 0.1,
            q,
        }
    }

    #[test]
    fn a_peer_failure_is_one_sentence_without_the_scripts_output() {
        let installed =
            "Mitsuba 3 is not installed here (`pip install mitsuba`): peer column skipped";
        assert_eq!(peer_not_run(installed), format!("Not run: {installed}."));
        for why in [
            "mitsuba script failed: Traceback (most recent call last)",
            "cannot run scripts/mitsuba_peer.py: No such file",
            "line one\nline two",
        ] {
            let s = peer_not_run(why);
            assert!(
                s.contains("results.json") && !s.contains("Traceback") && !s.contains("line"),
                "{s}"
            );
        }
    }

    #[test]
    fn a_sweep_is_monotone_within_its_slack_and_met_at_both_ends() {
        let good = [
            point(0.25, 0.6, 0.85),
            point(1.0, 0.4, 0.95),
            point(4.0, 0.25, 1.2),
        ];
        let refs: Vec<&SweepPoint> = good.iter().rev().collect();
        let c = sweep_check("s", 60.0, &refs);
        assert!(c.monotone && c.met(), "{c:?}");
        assert_eq!((c.cheapest_time, c.best_q), (0.25, 0.85));
        // Time rising by 0.01 is timing noise; by 0.05 it is not monotone.
        let noisy = [point(0.5, 0.40, 0.9), point(1.0, 0.41, 0.95)];
        assert!(sweep_check("s", 60.0, &noisy.iter().collect::<Vec<_>>()).monotone);
        let rising = [point(0.5, 0.40, 0.9), point(1.0, 0.45, 0.95)];
        assert!(!sweep_check("s", 60.0, &rising.iter().collect::<Vec<_>>()).monotone);
        // Q falling as t0 grows (more error allowed, less error got) is not monotone.
        let q_falls = [point(0.5, 0.40, 0.95), point(1.0, 0.30, 0.9)];
        assert!(!sweep_check("s", 60.0, &q_falls.iter().collect::<Vec<_>>()).monotone);
        // Monotone, but never cheap enough.
        let dear = [point(0.5, 0.5, 0.85), point(1.0, 0.4, 0.95)];
        assert!(!sweep_check("s", 60.0, &dear.iter().collect::<Vec<_>>()).met());
    }
}

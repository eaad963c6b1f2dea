//! The progressive loop of F&P04 §4.2 (and Guo's baseline on the same machinery).
//!
//! A render: analyse the image (§4.1: object ids, surface normals, texture albedos),
//! trace the first sample set, triangulate and shade it. Then each iteration reads as its
//! phases:
//! 1. classify the triangles ([`classifier`]: the perceptual distance between successive
//!    frames, or Guo's contrast test);
//! 2. plan what each class asks for ([`plan`]);
//! 3. stop, or not ([`budget`]);
//! 4. emit the frame (after the first one, the perceptual oracle measures what noise alone
//!    does to its distance: [`noise_twin`]);
//! 5. trace the plan, re-triangulate ([`Mesh`]), shade ([`samples`]), and fill the complex
//!    triangles along their rupture ([`fill`]).
//!
//! Each pixel is traced at most once ([`samples::SampleSet`]); the triangulation is
//! incremental and its vertices are the traced pixels, except those whose footprint spans
//! several objects ([`Run::first_trace`]). When tracing every pixel of the triangles still
//! open costs less than another iteration, the loop does that and ends
//! ([`Plan::finish_if_cheaper`]).

mod budget;
mod classifier;
mod cost;
mod fill;
mod judge;
mod noise_twin;
mod plan;
mod samples;

pub use budget::Stop;
pub use judge::{Judge, VisionJudge};
pub use plan::endgame_pixels;

use super::classify::guarded_t1;
use super::complex::ContourWalker;
use super::mesh::{rasterise, Raster, Tri, Triangulator};
use super::preview;
use super::reconstruct::Averaging;
use super::seeding::initial_samples;
use super::{ClassCell, Frame, IterationStats, RenderStats, TriangleClass};
use crate::cancel::{CancelToken, Cancelled};
use crate::raster::{Image, LinearImage, PixelCoord, Rgb};
use crate::scene::ObjectId;
use crate::tracer::{self, PixelOracle};
use budget::Budget;
use classifier::{Classification, Classifier, Guo, Perceptual, View};
use plan::Plan;
use samples::SampleSet;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Pixels per `trace_pixels` call; time and pixel budgets are checked between calls.
const CHUNK: usize = 4096;

/// Which classification oracle drives the loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Oracle {
    /// F&P04: the perceptual distance between successive frames.
    Perceptual,
    /// Guo 1998 via Mitchell's contrast test (spec §4.3); no final class.
    Guo,
}

impl Oracle {
    /// The render mode it makes (`RenderStats::mode`).
    fn mode(self) -> &'static str {
        match self {
            Oracle::Perceptual => "progressive",
            Oracle::Guo => "guo",
        }
    }
}

/// Everything the loop needs besides the pixel oracle.
#[derive(Clone, Debug)]
pub struct Settings {
    pub oracle: Oracle,
    pub t0: f32,
    pub t1: Option<f32>,
    pub initial_rate: f32,
    pub max_iterations: u32,
    pub seed: u64,
    /// Display exposure (Guo's contrast test and rupture jumps use displayed values).
    pub exposure: f32,
    pub max_pixels: Option<u64>,
    pub max_time: Option<Duration>,
    /// The scene's samples per pixel: the noise twins use the same estimator.
    pub samples_per_pixel: u32,
    /// Noise-aware classification ([`super::noise`]); perceptual mode only.
    pub noise_compensation: bool,
    /// Run the loop even where tracing every pixel costs less ([`cost::loop_pays`]).
    pub force_loop: bool,
    /// The declared viewing condition: how much averaging the reconstruction needs
    /// ([`super::reconstruct`]).
    pub pixels_per_degree: f32,
}

/// The Delaunay triangulation of the traced pixels (F&P04 §4.2) as triangles, and which
/// triangle owns each pixel.
pub(super) struct Mesh {
    pub tris: Vec<Tri>,
    pub raster: Raster,
}

impl Mesh {
    fn of(tri: &Triangulator, w: u32, h: u32) -> Self {
        let tris = tri.triangles();
        let raster = rasterise(&tris, w, h);
        Self { tris, raster }
    }
}

/// One render's state: the samples, the budget and the statistics.
struct Run<'a, O: PixelOracle> {
    oracle: &'a O,
    s: &'a Settings,
    px: SampleSet,
    budget: Budget,
    start: Instant,
    stats: RenderStats,
    it: IterationStats,
}

/// Runs the loop. `judge` is used in perceptual mode only.
pub fn run<O: PixelOracle>(
    oracle: &O,
    s: &Settings,
    judge: &mut dyn Judge,
    on_frame: &mut dyn FnMut(&Frame),
    cancel: &CancelToken,
) -> Result<Frame, Cancelled> {
    run_reporting(oracle, s, judge, on_frame, &|_, _| {}, cancel)
}

/// [`run`], also reporting `(pixels done, pixels in all)` through `on_pixels` while a
/// render the loop cannot pay for is traced whole ([`cost`]), which has no frame until
/// its end.
pub fn run_reporting<O: PixelOracle>(
    oracle: &O,
    s: &Settings,
    judge: &mut dyn Judge,
    on_frame: &mut dyn FnMut(&Frame),
    on_pixels: &(dyn Fn(usize, usize) + Sync),
    cancel: &CancelToken,
) -> Result<Frame, Cancelled> {
    if cancel.is_cancelled() {
        return Err(Cancelled);
    }
    let start = Instant::now();
    let before = match before_the_loop(oracle, s, start, on_frame, on_pixels, cancel)? {
        Ahead::Loop(before) => before,
        Ahead::TracedWhole(frame) => return Ok(*frame),
    };
    let mut r = Run::new(oracle, s, start, before);
    let (ids, seeds) = r.analyse();
    if r.px.w < 2 || r.px.h < 2 {
        return r.trace_whole(ids, on_frame, cancel);
    }
    let first = r.first_trace(&seeds, cancel)?;
    let mut st = r.first_mesh(&first, ids.pixels());
    let mut classifier = r.classifier(judge);
    loop {
        if cancel.is_cancelled() {
            return Err(Cancelled);
        }
        // 1. Classify.
        let mut c = r.classify(&mut st, &mut *classifier, ids.pixels());
        // 2. Plan: what the classes ask for, or the rest at once when that is cheaper.
        let (plan, finishing) = r.plan(&mut st, &mut c, ids.pixels());
        // 3. Stop?
        let stop = r.stop(&st, &plan, finishing);
        // 4. Emit the frame.
        let image = std::mem::replace(&mut st.cur, Image::filled(0, 0, Rgb::ZERO));
        let frame = r.frame(
            st.iter,
            image,
            c,
            &st.mesh.raster,
            classifier.t1(),
            stop,
            &ids,
        );
        on_frame(&frame);
        if stop.is_some() {
            return Ok(frame);
        }
        st.cur = frame.image;
        if st.iter == 0 && classifier.wants_noise() {
            r.noise_twin(
                &first,
                &st.mesh,
                &st.tri,
                ids.pixels(),
                &st.cur,
                &mut *classifier,
                cancel,
            )?;
        }
        // 5. Trace, re-triangulate, shade, fill.
        r.advance(
            &mut st,
            &plan,
            finishing,
            &*classifier,
            ids.pixels(),
            cancel,
        )?;
    }
}

/// How a render begins, before the loop's per-pixel state exists.
enum Ahead {
    /// The loop runs.
    Loop(Before),
    /// The paths are too cheap for the loop: the render was traced whole ([`cost`]).
    TracedWhole(Box<Frame>),
}

/// A preview of a large image (streamed before anything else, [`preview`]), then the cost
/// probe, which may trace the render whole.
fn before_the_loop<O: PixelOracle>(
    oracle: &O,
    s: &Settings,
    start: Instant,
    on_frame: &mut dyn FnMut(&Frame),
    on_pixels: &(dyn Fn(usize, usize) + Sync),
    cancel: &CancelToken,
) -> Result<Ahead, Cancelled> {
    let (w, h) = oracle.size();
    // Before the render's per-pixel state, which takes ~0.1 s to allocate at 2048².
    let preview_ms = if w as usize * h as usize >= preview::FROM_PIXELS {
        let f = preview::frame(oracle, s.samples_per_pixel, s.seed, s.oracle.mode(), cancel)?;
        on_frame(&f);
        f.stats.trace_ms
    } else {
        0.0
    };
    Ok(match cost::probe(oracle, s, cancel)? {
        cost::Verdict::Loop { probe_ms } => Ahead::Loop(Before {
            preview_ms,
            probe_ms,
        }),
        cost::Verdict::Reference { probe_ms } => {
            let before = preview_ms + probe_ms;
            let f = cost::reference(oracle, s, start, before, on_pixels, cancel)?;
            on_frame(&f);
            Ahead::TracedWhole(Box::new(f))
        }
    })
}

/// What a render spent before the loop: the preview's trace and the cost probe, ms.
struct Before {
    preview_ms: f64,
    probe_ms: f64,
}

/// What the loop carries from one iteration to the next.
struct LoopState {
    tri: Triangulator,
    mesh: Mesh,
    /// This iteration's picture, and the previous one (the classifier compares them).
    cur: LinearImage,
    prev: Option<LinearImage>,
    /// The last distance map measured, shown once nothing is left to judge.
    last_distance: Option<Image<f32>>,
    contours: ContourWalker,
    iter: u32,
    /// The open triangles were traced whole ([`Plan::finish_if_cheaper`]).
    finished: bool,
}

impl<'a, O: PixelOracle> Run<'a, O> {
    /// The first sample set triangulated and shaded: the state of iteration 0.
    fn first_mesh(&mut self, first: &[PixelCoord], ids: &[ObjectId]) -> LoopState {
        let (w, h) = self.oracle.size();
        let t = Instant::now();
        let mut tri = Triangulator::new();
        tri.insert(first);
        let mesh = Mesh::of(&tri, w, h);
        let cur = self.shaded(&mesh, &tri, ids);
        self.it.triangulate_ms += t.elapsed().as_secs_f64() * 1e3;
        LoopState {
            tri,
            mesh,
            cur,
            prev: None,
            last_distance: None,
            contours: ContourWalker::new(w, self.px.n),
            iter: 0,
            finished: false,
        }
    }

    /// Phase 1: each triangle's class; all final once every pixel is traced or the rest
    /// was traced whole (nothing is left to judge).
    fn classify(
        &mut self,
        st: &mut LoopState,
        classifier: &mut dyn Classifier,
        ids: &[ObjectId],
    ) -> Classification {
        let c = if self.px.all_traced() || st.finished {
            let mut c = Classification::uniform(TriangleClass::Final, st.mesh.tris.len(), true);
            c.distance = st.last_distance.clone();
            c
        } else {
            let view = View {
                samples: &self.px,
                mesh: &st.mesh,
                ids,
                prev: st.prev.as_ref(),
                cur: &st.cur,
                iteration: st.iter,
            };
            classifier.classify(&view, &mut st.contours)
        };
        self.it.metric_ms += c.metric_ms;
        if c.distance.is_some() {
            st.last_distance = c.distance.clone();
        }
        c
    }

    /// Phase 2: the pixels the classes ask for, and whether they are instead every open
    /// pixel at once, which ends the render ([`Plan::finish_if_cheaper`]).
    fn plan(
        &mut self,
        st: &mut LoopState,
        c: &mut Classification,
        ids: &[ObjectId],
    ) -> (Plan, bool) {
        let mut plan = if st.finished {
            Plan::default()
        } else {
            Plan::new(
                &mut self.px,
                &st.mesh,
                &mut c.classes,
                ids,
                &mut st.contours,
            )
        };
        self.it.open_pixels = plan::open_pixels(&self.px, &st.mesh, &c.classes);
        let finishing = !st.finished
            && !plan.work.is_empty()
            && plan.finish_if_cheaper(
                &self.px,
                &st.mesh,
                &c.classes,
                self.it.open_pixels,
                self.s.samples_per_pixel,
            );
        (plan, finishing)
    }

    /// Phase 3: why the render ends here, if it does ([`budget`]); otherwise the plan
    /// goes into this iteration's statistics.
    fn stop(&mut self, st: &LoopState, plan: &Plan, finishing: bool) -> Option<Stop> {
        let stop = self
            .budget
            .stop(self.px.all_traced(), plan.work.is_empty(), st.iter)
            .map(|stop| match stop {
                Stop::AllFinal if st.finished => Stop::TracedRest,
                stop => stop,
            });
        if stop.is_none() {
            self.it.planned_pixels = plan.work.len() as u64;
            self.it.finishing = finishing;
        }
        stop
    }

    /// Phase 5: the plan traced and triangulated, the next picture shaded and its complex
    /// triangles filled along their rupture; the next iteration's state (`finishing`: the
    /// plan was every open pixel, so nothing is left to judge).
    fn advance(
        &mut self,
        st: &mut LoopState,
        plan: &Plan,
        finishing: bool,
        classifier: &dyn Classifier,
        ids: &[ObjectId],
        cancel: &CancelToken,
    ) -> Result<(), Cancelled> {
        let (next_mesh, t) = self.refine(&mut st.tri, &plan.work, st.iter + 1, cancel)?;
        let mut next = self.shaded(&next_mesh, &st.tri, ids);
        for &k in &plan.complex {
            fill::fill_complex(
                &st.mesh.tris[k],
                &st.mesh.raster,
                k,
                &self.px,
                classifier,
                self.s.exposure,
                &mut st.contours,
                next.pixels_mut(),
            );
        }
        self.it.triangulate_ms += t.elapsed().as_secs_f64() * 1e3;
        st.mesh = next_mesh;
        st.prev = Some(std::mem::replace(&mut st.cur, next));
        st.finished = finishing;
        st.iter += 1;
        Ok(())
    }
}

impl<'a, O: PixelOracle> Run<'a, O> {
    /// A render begun at `start` (its budget counts from there), having spent `before`.
    fn new(oracle: &'a O, s: &'a Settings, start: Instant, before: Before) -> Self {
        let (w, h) = oracle.size();
        let mode = s.oracle.mode();
        Self {
            oracle,
            s,
            px: SampleSet::new(w, h, s.samples_per_pixel),
            budget: Budget::new(s.max_pixels, s.max_time, s.max_iterations, start),
            start,
            stats: RenderStats {
                mode: mode.into(),
                width: w,
                height: h,
                trace_ms: before.preview_ms,
                analysis_ms: before.probe_ms,
                ..RenderStats::default()
            },
            it: IterationStats::default(),
        }
    }

    /// §4.1: the object-id map (one primary ray per pixel) and the surface normals beside
    /// it, the pixels whose footprint spans several objects, the texture albedos (textured
    /// scenes only: the texture's detail comes from them, mesh.rs `gouraud`) and the first
    /// sample set (contour pixels of the id map, then uniform ones), as pixel indices.
    fn analyse(&mut self) -> (Arc<Image<ObjectId>>, Vec<usize>) {
        let t = Instant::now();
        let maps = tracer::analysis_maps(self.oracle);
        let ids = Arc::new(maps.ids);
        (self.px.normals, self.px.mixed) = (maps.normals, maps.mixed);
        self.px.albedo = maps.albedo;
        let seeds = initial_samples(&ids, self.s.initial_rate, self.s.seed);
        let seeds = seeds.iter().map(|&p| self.px.index(p)).collect();
        self.stats.analysis_ms += t.elapsed().as_secs_f64() * 1e3;
        (ids, seeds)
    }

    /// The classification oracle of `Settings::oracle`. The perceptual one discounts noise
    /// when noise compensation is on and anything can become final (T0 > 0); it measures
    /// that noise after the first frame ([`Self::noise_twin`]).
    fn classifier<'j>(&self, judge: &'j mut dyn Judge) -> Box<dyn Classifier + 'j> {
        let s = self.s;
        let t0 = f64::from(s.t0);
        let t1 = s.t1.map(|v| guarded_t1(t0, f64::from(v)));
        match s.oracle {
            Oracle::Perceptual => Box::new(Perceptual {
                judge,
                t0,
                t1,
                noise: None,
                compensates: s.noise_compensation && s.t0 > 0.0,
                exposure: s.exposure,
            }),
            Oracle::Guo => Box::new(Guo {
                t1,
                exposure: s.exposure,
                finals: s.t0 > 0.0,
            }),
        }
    }

    /// Traces the first sample set and every pixel whose footprint spans several objects;
    /// returns the first set's pixels, the triangulation's first vertices.
    ///
    /// A mixed pixel's value blends the objects its footprint covers (an antialiased
    /// silhouette, a horizon, a wire thinner than a pixel): no object's vertices can
    /// interpolate it, and as a vertex it would spread that blend over the interior of
    /// the object its centre lies on. So it is traced, shown as traced, and kept out of
    /// the triangulation, except at the image corners, which keep every pixel inside the
    /// triangulation's hull. Measured on a 40-scene corpus at each scene's declared
    /// viewing condition: Q ≤ 1 on 21 scenes instead of 19, median Q 0.99 instead of
    /// 1.03 (keeping mixed pixels as vertices that no other pixel interpolates scored
    /// 20 and 1.03: the triangles along a contour then shade from one vertex).
    fn first_trace(
        &mut self,
        seeds: &[usize],
        cancel: &CancelToken,
    ) -> Result<Vec<PixelCoord>, Cancelled> {
        let mut list = Vec::with_capacity(seeds.len());
        for &i in seeds {
            self.px.push(i, &mut list);
        }
        for i in 0..self.px.n {
            if self.px.mixed[i] {
                self.px.push(i, &mut list);
            }
        }
        self.px.unqueue(&list);
        let (w, h) = (self.px.w, self.px.h);
        let corner = |p: &PixelCoord| (p.x == 0 || p.x == w - 1) && (p.y == 0 || p.y == h - 1);
        let traced = self.trace(&list, 0, cancel)?;
        Ok(traced
            .into_iter()
            .filter(|p| corner(p) || !self.px.mixed[self.px.index(*p)])
            .collect())
    }

    /// Traces `list` (pixel indices, untraced, no duplicates) in chunks, honouring the
    /// pixel and time budgets and the cancel token between chunks. Returns what was traced.
    fn trace(
        &mut self,
        list: &[usize],
        iter: u32,
        cancel: &CancelToken,
    ) -> Result<Vec<PixelCoord>, Cancelled> {
        let t = Instant::now();
        let list = self.budget.allow(list, self.px.count);
        let mut done = Vec::with_capacity(list.len());
        for chunk in list.chunks(CHUNK) {
            if cancel.is_cancelled() {
                return Err(Cancelled);
            }
            // The first sample set is always traced whole (frame 0 needs a triangulation);
            // later sets stop at the time budget between chunks.
            if iter > 0 && self.budget.time_up() {
                self.budget.time_hit();
                break;
            }
            // Raster order inside a chunk: neighbouring pixels follow similar paths through
            // the BVH and the textures, so tracing them together keeps caches warm (the
            // work list comes in triangle order). Values do not depend on order.
            let mut sorted = chunk.to_vec();
            sorted.sort_unstable();
            let coords: Vec<PixelCoord> = sorted.iter().map(|&i| self.px.coord(i)).collect();
            let estimates = tracer::trace_estimates(self.oracle, &coords, cancel)?;
            for (&i, e) in sorted.iter().zip(estimates) {
                self.px.record(i, e, iter);
            }
            done.extend_from_slice(&coords);
        }
        self.it.trace_ms += t.elapsed().as_secs_f64() * 1e3;
        self.it.pixels_traced += done.len() as u64;
        if self.budget.time_up() {
            self.budget.time_hit();
        }
        Ok(done)
    }

    /// Traces `work` and inserts it into the triangulation; the new mesh, and when the
    /// loop began to wait for it (triangulation time counts from there).
    ///
    /// The triangulation depends on the new samples' positions, not their values: when no
    /// budget can cut the trace short (every queued pixel will be traced), they are
    /// inserted and rasterised on another thread while they are traced. Spade's insertion
    /// is serial; overlapped, it costs the trace about half its time instead of all of it.
    /// The result is the same triangulation (same points, same insertion order).
    fn refine(
        &mut self,
        tri: &mut Triangulator,
        work: &[usize],
        iter: u32,
        cancel: &CancelToken,
    ) -> Result<(Mesh, Instant), Cancelled> {
        let (w, h) = (self.px.w, self.px.h);
        if self.budget.can_cut() {
            let new = self.trace(work, iter, cancel)?;
            let t = Instant::now();
            tri.insert(&new);
            return Ok((Mesh::of(tri, w, h), t));
        }
        let coords: Vec<PixelCoord> = work.iter().map(|&i| self.px.coord(i)).collect();
        let (traced, mesh, t) = std::thread::scope(|sc| {
            let side = sc.spawn(move || {
                tri.insert(&coords);
                Mesh::of(tri, w, h)
            });
            let traced = self.trace(work, iter, cancel);
            (traced, side.join(), Instant::now())
        });
        traced?;
        // A panic there is the same bug as one inline: hand it on unchanged.
        let mesh = mesh.unwrap_or_else(|e| std::panic::resume_unwind(e));
        Ok((mesh, t))
    }

    /// A new frame shaded on `mesh` ([`SampleSet::shade`]).
    fn shaded(&mut self, mesh: &Mesh, tri: &Triangulator, ids: &[ObjectId]) -> LinearImage {
        let (w, h) = (self.px.w, self.px.h);
        let mut out = Image::filled(w, h, Rgb::ZERO);
        let averaging = Averaging::for_render(self.s.pixels_per_degree, self.s.t0);
        self.px.shade(
            &mesh.tris,
            &mesh.raster,
            tri,
            ids,
            averaging,
            out.pixels_mut(),
        );
        out
    }

    /// Iteration `iter`'s frame, its statistics closed.
    #[allow(clippy::too_many_arguments)]
    fn frame(
        &mut self,
        iter: u32,
        image: LinearImage,
        c: Classification,
        raster: &Raster,
        t1: Option<f64>,
        stop: Option<Stop>,
        ids: &Arc<Image<ObjectId>>,
    ) -> Frame {
        let (w, h) = (self.px.w, self.px.h);
        let classes = if c.shown {
            let cells: Vec<ClassCell> = raster
                .owner
                .iter()
                .map(|&o| {
                    c.classes
                        .get(o as usize)
                        .map_or(ClassCell::None, |&k| k.into())
                })
                .collect();
            Image::from_vec(w, h, cells).unwrap_or_else(|| Image::filled(w, h, ClassCell::None))
        } else {
            Image::filled(w, h, ClassCell::None)
        };
        let [nf, ns, nc] = counts(&c.classes);
        let mean = c.mean_distance;
        self.it.iteration = iter;
        self.it.mean_distance = if mean.is_finite() { mean } else { 0.0 };
        self.it.triangles_final = nf;
        self.it.triangles_smooth = ns;
        self.it.triangles_complex = nc;
        let it = std::mem::take(&mut self.it);
        let st = &mut self.stats;
        st.trace_ms += it.trace_ms;
        st.metric_ms += it.metric_ms;
        st.triangulate_ms += it.triangulate_ms;
        if mean.is_finite() {
            st.final_mean_distance = mean;
        }
        st.triangles_final = nf;
        st.triangles_smooth = ns;
        st.triangles_complex = nc;
        st.t1_used = t1;
        st.iterations = iter + 1;
        st.per_iteration.push(it);
        st.stop_reason = stop.map(|s| s.as_str().to_string());
        self.finish_stats();
        Frame {
            iteration: iter,
            image,
            samples: self.px.layer(iter),
            distance: c.distance,
            classes,
            objects: Arc::clone(ids),
            stats: self.stats.clone(),
            last: stop.is_some(),
            preview: false,
        }
    }

    /// An image one pixel wide or high has only collinear samples, hence no triangle: it
    /// is traced whole (at most 16384 pixels by the scene limits) instead of interpolated.
    fn trace_whole(
        mut self,
        ids: Arc<Image<ObjectId>>,
        on_frame: &mut dyn FnMut(&Frame),
        cancel: &CancelToken,
    ) -> Result<Frame, Cancelled> {
        let all: Vec<usize> = (0..self.px.n).collect();
        self.trace(&all, 0, cancel)?;
        let (w, h) = (self.px.w, self.px.h);
        let image = Image::from_fn(w, h, |x, y| {
            self.px.rad[y as usize * w as usize + x as usize]
        });
        let it = std::mem::take(&mut self.it);
        self.stats.trace_ms += it.trace_ms;
        self.stats.iterations = 1;
        self.stats.per_iteration.push(it);
        self.stats.stop_reason = Some(Stop::NoTriangles.as_str().to_string());
        self.finish_stats();
        let frame = Frame {
            iteration: 0,
            image,
            samples: self.px.layer(0),
            distance: None,
            classes: Image::filled(w, h, ClassCell::None),
            objects: ids,
            stats: self.stats,
            last: true,
            preview: false,
        };
        on_frame(&frame);
        Ok(frame)
    }

    fn finish_stats(&mut self) {
        self.stats.total_ms = self.start.elapsed().as_secs_f64() * 1e3;
        self.stats.pixels_traced = self.px.count;
        self.stats.pixel_fraction = self.px.count as f64 / self.px.n.max(1) as f64;
    }
}

/// Triangles per class: final, smooth, complex.
fn counts(classes: &[TriangleClass]) -> [u64; 3] {
    let mut n = [0u64; 3];
    for c in classes {
        n[match c {
            TriangleClass::Final => 0,
            TriangleClass::Smooth => 1,
            TriangleClass::Complex => 2,
        }] += 1;
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progressive::SampleCell;
    use crate::tracer::Estimate;

    struct Fn2<F>(u32, u32, F);
    impl<F: Fn(u32, u32) -> Rgb + Sync> PixelOracle for Fn2<F> {
        fn size(&self) -> (u32, u32) {
            (self.0, self.1)
        }
        fn radiance(&self, p: PixelCoord) -> Rgb {
            (self.2)(p.x, p.y)
        }
        fn radiance_with(&self, p: PixelCoord, _: u32, _: u64) -> Rgb {
            (self.2)(p.x, p.y)
        }
        fn object_id(&self, _: PixelCoord) -> ObjectId {
            0
        }
    }

    /// [`Fn2`] whose every estimate casts `rays` rays.
    struct Rays<F>(Fn2<F>, u32);
    impl<F: Fn(u32, u32) -> Rgb + Sync> PixelOracle for Rays<F> {
        fn size(&self) -> (u32, u32) {
            self.0.size()
        }
        fn radiance(&self, p: PixelCoord) -> Rgb {
            self.0.radiance(p)
        }
        fn radiance_with(&self, p: PixelCoord, n: u32, seed: u64) -> Rgb {
            self.0.radiance_with(p, n, seed)
        }
        fn object_id(&self, p: PixelCoord) -> ObjectId {
            self.0.object_id(p)
        }
        fn estimate(&self, p: PixelCoord) -> Estimate {
            Estimate {
                rays: self.1,
                ..self.0.estimate(p)
            }
        }
    }

    #[test]
    fn paths_too_cheap_for_the_loop_are_traced_whole_as_the_reference() {
        let shade = |x: u32, y: u32| Rgb::new(x as f32 * 0.01, y as f32 * 0.02, 0.1);
        let s = settings(Oracle::Perceptual);
        let reported = std::sync::atomic::AtomicUsize::new(0);
        let render = |rays: u32, s: &Settings| {
            let mut frames = Vec::new();
            let o = Rays(Fn2(60, 40, shade), rays);
            let mut j = Const(Some(0.0), 0);
            let on_pixels = |done: usize, all: usize| {
                assert_eq!(all, 60 * 40);
                reported.fetch_max(done, std::sync::atomic::Ordering::Relaxed);
            };
            let f = run_reporting(
                &o,
                s,
                &mut j,
                &mut |f| frames.push(f.iteration),
                &on_pixels,
                &CancelToken::new(),
            )
            .expect("runs");
            (f, frames, j.1)
        };
        let (f, frames, judged) = render(20, &s);
        assert_eq!(f.stats.stop_reason.as_deref(), Some("reference_cheaper"));
        assert_eq!((frames, judged), (vec![0], 0), "one frame, no metric");
        let done = reported.load(std::sync::atomic::Ordering::Relaxed);
        assert_eq!(done, 60 * 40, "its pixels are reported as traced");
        assert_eq!(f.stats.pixel_fraction, 1.0);
        let reference =
            tracer::render_reference(&Fn2(60, 40, shade), &CancelToken::new(), &|_, _| {})
                .expect("runs");
        assert_eq!(f.image.pixels(), reference.pixels());
        // Dearer paths, a budget, or `force_loop` keep the loop.
        let (f, frames, _) = render(40, &s);
        assert_ne!(f.stats.stop_reason.as_deref(), Some("reference_cheaper"));
        assert!(frames.len() > 1 && f.stats.pixel_fraction < 1.0);
        let forced = Settings {
            force_loop: true,
            ..settings(Oracle::Perceptual)
        };
        let budget = Settings {
            max_pixels: Some(2000),
            ..settings(Oracle::Perceptual)
        };
        for s in [&forced, &budget] {
            let (f, frames, _) = render(20, s);
            assert!(frames.len() > 1, "{:?}", f.stats.stop_reason);
        }
    }

    /// A judge that answers a constant map, or nothing.
    struct Const(Option<f32>, u32);
    impl Judge for Const {
        fn distance(
            &mut self,
            _: &LinearImage,
            cur: &LinearImage,
            _: &[PixelCoord],
            _: u32,
        ) -> Option<Image<f32>> {
            self.1 += 1;
            self.0.map(|v| Image::filled(cur.width(), cur.height(), v))
        }
    }

    fn settings(oracle: Oracle) -> Settings {
        Settings {
            oracle,
            t0: 1.0,
            t1: None,
            initial_rate: 0.02,
            max_iterations: 1000,
            seed: 3,
            exposure: 1.0,
            max_pixels: None,
            max_time: None,
            // Dear enough pixels that the loop never finds tracing the rest cheaper than
            // an iteration (`Plan::finish_if_cheaper`) on these small images.
            samples_per_pixel: 4096,
            noise_compensation: true,
            force_loop: false,
            pixels_per_degree: 28.0,
        }
    }

    fn go(s: &Settings, judge: &mut dyn Judge) -> (Frame, usize) {
        let o = Fn2(30, 20, |x: u32, y: u32| {
            Rgb::new(x as f32 * 0.01, y as f32 * 0.02, 0.1)
        });
        let mut frames = 0;
        let f =
            run(&o, s, judge, &mut |_| frames += 1, &CancelToken::new()).expect("not cancelled");
        (f, frames)
    }

    #[test]
    fn a_large_image_shows_a_preview_before_its_first_iteration() {
        let o = Fn2(600, 500, |x: u32, y: u32| {
            Rgb::new(x as f32 * 1e-3, y as f32 * 1e-3, 0.2)
        });
        let mut seen = Vec::new();
        let mut on_frame = |f: &Frame| seen.push((f.iteration, f.preview, f.stats.pixels_traced));
        let s = settings(Oracle::Perceptual);
        run(
            &o,
            &s,
            &mut Const(Some(0.0), 0),
            &mut on_frame,
            &CancelToken::new(),
        )
        .expect("runs");
        assert_eq!(
            seen[0],
            (0, true, 0),
            "a preview, no pixel of the image traced"
        );
        assert_eq!((seen[1].0, seen[1].1), (0, false));
        assert!(seen[1..].iter().all(|f| !f.1) && seen.len() == 3);
        let small = Fn2(30, 20, |_: u32, _: u32| Rgb::ZERO);
        let mut frames = 0;
        run(
            &small,
            &s,
            &mut Const(Some(0.0), 0),
            &mut |f| frames += usize::from(f.preview),
            &CancelToken::new(),
        )
        .expect("runs");
        assert_eq!(
            frames, 0,
            "a small image's first frame comes as fast as a preview"
        );
    }

    #[test]
    fn a_zero_judge_makes_everything_final_after_the_second_frame() {
        let mut j = Const(Some(0.0), 0);
        let (f, frames) = go(&settings(Oracle::Perceptual), &mut j);
        assert_eq!((frames, j.1), (2, 1));
        assert_eq!(f.stats.stop_reason.as_deref(), Some("all_final"));
        assert_eq!(
            f.stats.t1_used,
            Some(1.001),
            "T1 of a zero first map is guarded above T0"
        );
    }

    #[test]
    fn the_noise_twin_is_traced_once_after_the_first_frame() {
        // Twins that differ (noise to measure) and twins equal bit for bit (an exact
        // oracle: nothing to measure): either way the first sample set is traced again
        // once, and the first frame goes out before it.
        for amp in [0.2, 0.0] {
            let o = Noisy { step: false, amp };
            let mut first_frame = None;
            let f = run(
                &o,
                &settings(Oracle::Perceptual),
                &mut Const(Some(5.0), 0),
                &mut |f: &Frame| {
                    first_frame.get_or_insert(f.stats.noise_probe_pixels);
                },
                &CancelToken::new(),
            )
            .expect("runs");
            let first_set = f.stats.per_iteration[0].pixels_traced;
            assert!(f.stats.iterations > 3 && first_set > 0, "amp {amp}");
            assert_eq!(first_frame, Some(0), "amp {amp}: no twin before frame 0");
            assert_eq!(f.stats.noise_probe_pixels, first_set, "amp {amp}");
        }
    }

    /// A flat or step-edged field with seed-dependent noise (so the noise twins differ),
    /// one object everywhere.
    struct Noisy {
        step: bool,
        amp: f32,
    }
    impl PixelOracle for Noisy {
        fn size(&self) -> (u32, u32) {
            (40, 30)
        }
        fn radiance(&self, p: PixelCoord) -> Rgb {
            self.radiance_with(p, 1, 0)
        }
        fn radiance_with(&self, p: PixelCoord, _: u32, seed: u64) -> Rgb {
            let h = ((u64::from(p.x) * 0x9E37_79B9) ^ (u64::from(p.y) * 0x85EB_CA6B) ^ seed)
                .wrapping_mul(0xBF58_476D_1CE4_E5B9);
            let n = ((h >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * self.amp;
            let base = if self.step && p.x >= 20 { 0.9 } else { 0.1 };
            Rgb::splat(base + n)
        }
        fn object_id(&self, _: PixelCoord) -> ObjectId {
            0
        }
    }

    /// Every frame distance is large, the twin noise small: the signal distance passes T1.
    struct Loud;
    impl Judge for Loud {
        fn distance(
            &mut self,
            _: &LinearImage,
            c: &LinearImage,
            _: &[PixelCoord],
            _: u32,
        ) -> Option<Image<f32>> {
            Some(Image::filled(c.width(), c.height(), 50.0))
        }
        fn noise_distance(
            &mut self,
            f: &LinearImage,
            _: &LinearImage,
            _: &[PixelCoord],
        ) -> Option<Image<f32>> {
            Some(Image::filled(f.width(), f.height(), 0.5))
        }
    }

    #[test]
    fn complex_triangles_need_a_discontinuity_beyond_the_noise() {
        let mut s = settings(Oracle::Perceptual);
        s.max_iterations = 2;
        s.t1 = Some(10.0);
        let complex = |o: &Noisy, s: &Settings| {
            let mut n = 0;
            run(
                o,
                s,
                &mut Loud,
                &mut |f| n += f.stats.triangles_complex,
                &CancelToken::new(),
            )
            .expect("not cancelled");
            n
        };
        // Flat field: every vertex differs by noise only → refined at centres, not complex.
        assert_eq!(
            complex(
                &Noisy {
                    step: false,
                    amp: 0.02
                },
                &s
            ),
            0
        );
        // A step 0.1 → 0.9 inside one object: the triangles across it stay complex.
        assert!(
            complex(
                &Noisy {
                    step: true,
                    amp: 0.02
                },
                &s
            ) > 0
        );
        // Without compensation F&P04 is unchanged: the flat field's triangles are complex.
        s.noise_compensation = false;
        assert!(
            complex(
                &Noisy {
                    step: false,
                    amp: 0.02
                },
                &s
            ) > 0
        );
    }

    /// Far from final left of x = 15, final right of it.
    struct HalfLoud;
    impl Judge for HalfLoud {
        fn distance(
            &mut self,
            _: &LinearImage,
            c: &LinearImage,
            _: &[PixelCoord],
            _: u32,
        ) -> Option<Image<f32>> {
            Some(Image::from_fn(c.width(), c.height(), |x, _| {
                if x < 15 {
                    50.0
                } else {
                    0.0
                }
            }))
        }
    }

    #[test]
    fn the_rest_is_traced_at_once_when_that_costs_less_than_an_iteration() {
        let mut s = settings(Oracle::Perceptual);
        s.noise_compensation = false;
        let (slow, slow_frames) = go(&s, &mut HalfLoud);
        assert_ne!(slow.stats.stop_reason.as_deref(), Some("traced_rest"));
        // Two samples a pixel: the whole image at first costs more than an iteration's
        // work over its 600 pixels, the open left half (< 300 pixels) less.
        s.samples_per_pixel = 2;
        let (f, frames) = go(&s, &mut HalfLoud);
        assert_eq!(f.stats.stop_reason.as_deref(), Some("traced_rest"));
        assert!(
            frames < slow_frames,
            "{frames} frames, {slow_frames} without"
        );
        let traced = f
            .samples
            .pixels()
            .iter()
            .filter(|&&c| c != SampleCell::Interpolated);
        assert!(traced.count() as u64 == f.stats.pixels_traced);
        for y in 0..20 {
            for x in 0..14 {
                assert_ne!(*f.samples.get(x, y), SampleCell::Interpolated, "({x}, {y})");
            }
        }
        assert!(
            f.stats.pixels_traced < 600,
            "the final right half is not traced"
        );
        // The iteration before the last said so, and planned exactly what the last traced:
        // every untraced pixel it left open.
        let its = &f.stats.per_iteration;
        let (before, last) = (&its[its.len() - 2], &its[its.len() - 1]);
        assert!(before.finishing && !last.finishing, "{its:?}");
        assert_eq!(before.planned_pixels, last.pixels_traced);
        assert_eq!(before.open_pixels, before.planned_pixels);
        assert_eq!((last.open_pixels, last.planned_pixels), (0, 0));
        assert!(its[..its.len() - 2]
            .iter()
            .all(|i| !i.finishing && i.open_pixels > 0));
    }

    /// Object 0 left of x = 15, object 1 right of it; column 15's footprint spans both and
    /// its value is their blend.
    struct Edge;
    impl PixelOracle for Edge {
        fn size(&self) -> (u32, u32) {
            (30, 20)
        }
        fn radiance(&self, p: PixelCoord) -> Rgb {
            Rgb::splat(match p.x {
                0..15 => 0.1,
                15 => 0.5,
                _ => 0.9,
            })
        }
        fn radiance_with(&self, p: PixelCoord, _: u32, _: u64) -> Rgb {
            self.radiance(p)
        }
        fn object_id(&self, p: PixelCoord) -> ObjectId {
            u32::from(p.x >= 15)
        }
        fn footprint_mixed(&self, p: PixelCoord, _: ObjectId) -> bool {
            p.x == 15
        }
    }

    #[test]
    fn a_mixed_footprint_is_traced_and_its_blend_spreads_nowhere() {
        let s = settings(Oracle::Perceptual);
        let f = run(
            &Edge,
            &s,
            &mut Const(Some(0.0), 0),
            &mut |_| {},
            &CancelToken::new(),
        )
        .expect("runs");
        for y in 0..20 {
            assert_eq!(*f.image.get(15, y), Rgb::splat(0.5), "the blend, traced");
            assert_ne!(*f.samples.get(15, y), SampleCell::Interpolated);
            for x in (0..15).chain(16..30) {
                let want = if x < 15 { 0.1 } else { 0.9 };
                let got = f.image.get(x, y).x;
                assert!((got - want).abs() < 1e-6, "({x}, {y}): {got}");
            }
        }
    }

    #[test]
    fn an_unavailable_judge_refines_until_everything_is_traced() {
        let mut j = Const(None, 0);
        let (f, _) = go(&settings(Oracle::Perceptual), &mut j);
        assert_eq!(f.stats.stop_reason.as_deref(), Some("all_traced"));
        assert_eq!(f.stats.pixels_traced, 600);
    }

    #[test]
    fn a_large_distance_makes_complex_triangles_and_budgets_stop_the_loop() {
        let mut j = Const(Some(50.0), 0);
        let mut s = settings(Oracle::Perceptual);
        s.max_pixels = Some(100);
        let (f, _) = go(&s, &mut j);
        assert_eq!(f.stats.stop_reason.as_deref(), Some("max_pixels"));
        assert_eq!(f.stats.pixels_traced, 100);
        s.max_pixels = None;
        s.max_time = Some(Duration::ZERO);
        let (f, frames) = go(&s, &mut j);
        assert_eq!(f.stats.stop_reason.as_deref(), Some("max_time"));
        assert!(
            frames <= 2 && f.stats.pixels_traced > 4,
            "the first set is traced whole"
        );
        s.max_time = None;
        s.max_iterations = 3;
        let (f, frames) = go(&s, &mut j);
        assert_eq!(
            (frames, f.stats.stop_reason.as_deref()),
            (3, Some("max_iterations"))
        );
        assert!(f.stats.triangles_complex > 0);
    }
}

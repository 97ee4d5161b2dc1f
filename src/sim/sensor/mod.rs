//! Simulated vision-based tactile sensors: TacTip, ViTac and ViTacTip.
//!
//! Data flow per frame: a [`DepthMap`] (object height over the undeformed skin, mm) and a
//! [`MotionState`] go into [`SensorSim::render`], which starts from the precomputed static
//! look ([`look::StaticLook`]: skin, illumination, field of view, marker lattice) and runs the
//! effect stages the [`Scene`] lists, in a fixed order:
//!
//! ```text
//! indentation field ─► contact_deformation ─► marker_displacement ─► see_through ─► markers
//!   ─► shading ─► motion_blur ─► vignetting ─► noise ─► 8-bit image
//! ```
//!
//! Each stage first works out what it needs on the coarse cells or on the band of rows the
//! contact reaches ([`stages`]); then every pixel row goes through all the stages while it is
//! in cache, and becomes bytes. Motion blur moves pixels across rows: when it has something to
//! blur, the rows before it fill a whole frame, it blurs that, and the rows after it follow.
//!
//! A stage runs only when the scene lists it and it applies to the kind (TacTip has an opaque
//! skin, so no see-through; ViTac has no markers, so no marker displacement). Every run of a
//! stage is counted ([`SensorSim::stage_counts`]), so tests can show that a scene without a
//! stage never runs it. [`SimCamera`] puts a simulator behind the [`crate::camera::Camera`]
//! seam, reading the simulated arm's truth; it applies the `stale_frame` stage.
//!
//! Everything is deterministic for a seed: the static look is seeded by `seed`, the noise by
//! `seed` and the `frame_key` of each render.

mod camera;
pub mod look;
mod scene;
pub mod shapes;
pub mod skin;
pub mod stages;

use std::borrow::Cow;
use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};

use image::RgbImage;

pub use camera::{DepthSource, SimCamera};
pub use scene::{Scene, SceneError, SceneLoadError, Stage};
pub use skin::{SKIN_PARAMETERS, SkinModel, SkinParameter};

use crate::geometry::DepthMap;
use crate::imaging::RowBand;
use crate::sensor::SensorKind;
use look::{Look, StaticLook};
use stages::{CellColumn, CellField, MarkerRows, RowSampler};

impl Stage {
    /// True when this stage has any effect on `kind` (TacTip's skin is opaque: nothing is seen
    /// through it; ViTac has no markers to displace).
    pub fn applies_to(self, kind: SensorKind) -> bool {
        match self {
            Stage::SeeThrough => kind != SensorKind::TacTip,
            Stage::MarkerDisplacement => kind != SensorKind::ViTac,
            _ => true,
        }
    }
}

/// A measured reference frame whose size differs from the simulator's.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("reference frame is {width}x{height}, the simulator renders {expected_width}x{expected_height}")]
pub struct ReferenceSizeError {
    pub width: u32,
    pub height: u32,
    pub expected_width: u32,
    pub expected_height: u32,
}

/// Motion of the contact in the image during the exposure (for motion blur).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MotionState {
    /// Image-space speed of the contact, px/s.
    pub speed_px_per_s: f32,
    /// Direction of the motion in the image, rad (0 = +x, pi/2 = +y, image y down).
    pub direction_rad: f32,
    /// Exposure time, s.
    pub exposure_s: f32,
}

impl MotionState {
    /// No motion.
    pub const STILL: MotionState = MotionState { speed_px_per_s: 0.0, direction_rad: 0.0, exposure_s: 0.0 };

    /// Length of the blur streak, px (0 for non-finite or negative inputs).
    pub fn streak_px(&self) -> f32 {
        let l = self.speed_px_per_s * self.exposure_s;
        if l.is_finite() && l > 0.0 { l } else { 0.0 }
    }
}

/// How many times each stage has run and the time spent in it, a snapshot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StageCounts {
    counts: [u64; Stage::COUNT],
    nanos: [u64; Stage::COUNT],
}

impl StageCounts {
    /// Runs of `stage`.
    pub fn get(&self, stage: Stage) -> u64 {
        self.counts[stage.index()]
    }
    /// Mean wall time of one run of `stage`, ms (0 when it never ran, or when stage timing is
    /// off: [`SensorSim::with_stage_timing`]).
    pub fn mean_ms(&self, stage: Stage) -> f64 {
        let i = stage.index();
        if self.counts[i] == 0 { 0.0 } else { self.nanos[i] as f64 / self.counts[i] as f64 * 1e-6 }
    }
    /// Runs of all stages together.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }
}

impl fmt::Display for StageCounts {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let parts: Vec<String> = Stage::ALL.iter().map(|s| format!("{s}={}", self.get(*s))).collect();
        f.write_str(&parts.join(" "))
    }
}

/// Optical constants of the simulated skins (the fitted mechanics are in [`SkinModel`]).
mod optics {
    /// Below this gap the object starts to show through a transparent skin, mm.
    pub const SEE_THROUGH_GAP_MM: f32 = 0.6;
    /// Reach of the tight glow hugging the contact at 512x512, px.
    pub const GLOW_NEAR_PX: f32 = 22.0;
    /// Reach of the broad haze around the contact at 512x512, px.
    pub const GLOW_FAR_PX: f32 = 70.0;
    /// Deepest press that still softens the see-through outline further, mm. Real skins are
    /// pressed a few mm at most (the press limits stop the arm before); without the cap a depth
    /// map of absurd heights would ask the blur for an absurd radius.
    pub const DEEPEST_EDGE_PRESS_MM: f32 = 5.0;
    /// How far the object's outline is softened by the skin it is seen through, at 512x512, px.
    pub const SEE_THROUGH_BLUR_PX: f32 = 2.0;
    /// Direction the light comes from in the image (unit vector; up-left).
    pub const LIGHT: [f32; 2] = [-0.6, -0.8];
}

/// Cell size of the coarse fields at 512x512, px.
const CELL_PX: f32 = 4.0;

thread_local! {
    /// The buffers frames are rendered in, kept between frames on this thread.
    static SCRATCH: std::cell::RefCell<FrameScratch> = std::cell::RefCell::new(FrameScratch::default());
}

thread_local! {
    /// Set by [`use_portable_rows`]: this thread draws its rows with the portable code.
    static PORTABLE_ROWS: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Makes this thread draw its frames' rows with the portable code even where the CPU has AVX2
/// (the AVX2 copy runs the same operations on wider registers and gives the same bytes); the
/// tests check the portable code with it.
#[doc(hidden)]
pub fn use_portable_rows(on: bool) {
    PORTABLE_ROWS.set(on);
}

/// Buffers reused from frame to frame on one thread.
#[derive(Default)]
struct FrameScratch {
    /// One f32 RGB row, or the whole frame when motion blur moves pixels across rows.
    buf: Vec<f32>,
    /// A measured look's transmission along the current row.
    transmit: Vec<f32>,
    /// Motion blur's change from the rest frame, and its blur.
    motion: [Vec<f32>; 2],
    /// The see-through glow sampled along the rows.
    glow: RowSampler,
    /// The see-through visibility band, and its blur's intermediate band.
    visibility: RowBand,
    visibility_scratch: RowBand,
}

/// The buffers and state the rows of one frame share: a measured look's transmission along the
/// row, the glow sampled along the rows, the visibility band, the markers drawn row by row.
struct RowWork<'a> {
    transmit: &'a mut Vec<f32>,
    sampler: &'a mut RowSampler,
    visibility: &'a RowBand,
    markers: Option<MarkerRows<'a>>,
}

/// What one frame's stages worked out before the pixel rows.
struct FramePlan {
    /// Where each pixel column samples the frame's cell fields.
    cols: Vec<CellColumn>,
    /// Skin displacement of a measured look, per cell (x, y).
    warp: Option<[CellField; 2]>,
    /// Marker positions to draw (a drawn look).
    markers: Option<Vec<[f32; 2]>>,
    /// See-through: the glow on cells, and whether the visibility band holds anything.
    see_through: Option<(CellField, bool)>,
    /// Shading factor per cell.
    shading: Option<CellField>,
    /// Length of the motion-blur streak, px, when it blurs anything.
    blur_px: Option<f32>,
    vignette: bool,
    noise_key: Option<u64>,
}

/// A simulated tactile sensor of one kind, one image size and one scene.
pub struct SensorSim {
    kind: SensorKind,
    scene: Scene,
    width: u32,
    height: u32,
    px_per_mm: f32,
    seed: u64,
    look: Look,
    skin: SkinModel,
    fixed: StaticLook,
    active: [bool; Stage::COUNT],
    /// Whether each stage's wall time is measured ([`SensorSim::with_stage_timing`]).
    timing: bool,
    counts: [AtomicU64; Stage::COUNT],
    nanos: [AtomicU64; Stage::COUNT],
}

impl fmt::Debug for SensorSim {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // The precomputed buffers are megabytes: leave them out.
        f.debug_struct("SensorSim")
            .field("kind", &self.kind)
            .field("scene", &self.scene.name)
            .field("width", &self.width)
            .field("height", &self.height)
            .field("px_per_mm", &self.px_per_mm)
            .field("seed", &self.seed)
            .finish_non_exhaustive()
    }
}

impl SensorSim {
    /// A simulator for `kind` rendering `width` x `height` images with the stages of `scene`.
    /// `px_per_mm` scales physical lengths (marker travel, deformation reach) to pixels; a
    /// non-finite or non-positive value falls back to 8.5 px/mm (the rig's usual scale).
    /// The static look is precomputed here.
    pub fn new(kind: SensorKind, scene: Scene, width: u32, height: u32, px_per_mm: f32, seed: u64) -> Self {
        let px_per_mm = if px_per_mm.is_finite() && px_per_mm > 0.0 {
            px_per_mm
        } else {
            tracing::warn!(px_per_mm, "invalid px/mm for the simulated sensor, using 8.5");
            8.5
        };
        let (width, height) = (width.max(1), height.max(1));
        let look = Look::of(kind);
        let fixed = StaticLook::build(&look, width, height, seed);
        let mut active = [false; Stage::COUNT];
        for s in &scene.stages {
            active[s.index()] = s.applies_to(kind);
        }
        Self {
            kind,
            scene,
            width,
            height,
            px_per_mm,
            seed,
            look,
            skin: SkinModel::of(kind),
            fixed,
            active,
            timing: false,
            counts: std::array::from_fn(|_| AtomicU64::new(0)),
            nanos: std::array::from_fn(|_| AtomicU64::new(0)),
        }
    }

    /// The same simulator with its static look taken from a measured no-contact frame of a
    /// real sensor (see [`look::StaticLook::from_reference`]); the reference must have the
    /// simulator's size.
    pub fn with_reference(mut self, reference: &RgbImage) -> Result<Self, ReferenceSizeError> {
        let wrong = || ReferenceSizeError {
            width: reference.width(),
            height: reference.height(),
            expected_width: self.width,
            expected_height: self.height,
        };
        if reference.dimensions() != (self.width, self.height) {
            return Err(wrong());
        }
        let fixed = StaticLook::from_reference(&self.look, reference.as_raw(), self.width, self.height, self.seed).ok_or_else(wrong)?;
        self.fixed = fixed;
        Ok(self)
    }

    /// The same simulator as another physical unit: its static look (rim specks, dust) is
    /// rebuilt from `unit_seed` while the per-frame noise keeps the run's seed. Collections
    /// with different plan seeds but the same unit seed see the same sensor, as a lab does.
    pub fn with_unit_seed(mut self, unit_seed: u64) -> Self {
        self.fixed = StaticLook::build(&self.look, self.width, self.height, unit_seed);
        self
    }

    /// The same simulator with another skin (a fit tries candidates with it); the values are
    /// brought into their ranges ([`SkinModel::clamped`]).
    pub fn with_skin(mut self, skin: SkinModel) -> Self {
        self.skin = skin.clamped();
        self
    }

    /// The skin the stages read.
    pub fn skin(&self) -> &SkinModel {
        &self.skin
    }

    pub fn kind(&self) -> SensorKind {
        self.kind
    }
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    pub fn px_per_mm(&self) -> f32 {
        self.px_per_mm
    }
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// True when `stage` runs for this sensor (listed by the scene and applicable to the kind).
    pub fn runs(&self, stage: Stage) -> bool {
        self.active[stage.index()]
    }

    /// How many times each stage has run since this simulator was made.
    pub fn stage_counts(&self) -> StageCounts {
        StageCounts {
            counts: std::array::from_fn(|i| self.counts[i].load(Ordering::Relaxed)),
            nanos: std::array::from_fn(|i| self.nanos[i].load(Ordering::Relaxed)),
        }
    }

    /// Records a run of `stage` done outside `render` (the camera's stale frames).
    pub(crate) fn count(&self, stage: Stage) {
        self.counts[stage.index()].fetch_add(1, Ordering::Relaxed);
    }

    /// The same simulator measuring the wall time of each stage ([`StageCounts::mean_ms`]).
    /// The stages run on each pixel row in turn, so this reads the clock several times a row:
    /// it slows rendering, and is meant for the stage benchmark.
    pub fn with_stage_timing(mut self) -> Self {
        self.timing = true;
        self
    }

    /// Runs `f` as part of `stage`, timing it when stage timing is on (it has no effect on the
    /// image).
    fn timed<T>(&self, stage: Stage, f: impl FnOnce() -> T) -> T {
        let t = self.clock();
        let out = f();
        self.clocked(stage, t);
        out
    }

    /// The time now, when stage timing is on. The row code times itself with this and
    /// [`SensorSim::clocked`] rather than through a closure: a closure is compiled on its own,
    /// without the AVX2 of the copy of the rows that calls it.
    #[inline(always)]
    fn clock(&self) -> Option<std::time::Instant> {
        self.timing.then(std::time::Instant::now)
    }

    /// Adds the time since `start` ([`SensorSim::clock`]) to `stage`.
    #[inline(always)]
    fn clocked(&self, stage: Stage, start: Option<std::time::Instant>) {
        if let Some(t) = start {
            let ns = u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX);
            self.nanos[stage.index()].fetch_add(ns, Ordering::Relaxed);
        }
    }

    /// Runs `stage`'s work on the whole frame if the stage is active, counting the run.
    fn stage(&self, stage: Stage, f: impl FnOnce()) {
        if self.runs(stage) {
            self.count(stage);
            self.timed(stage, f);
        }
    }

    /// The no-contact frame (all stages of the scene, still, no object, frame key 0).
    pub fn reference(&self) -> RgbImage {
        self.render(&DepthMap::empty(self.width, self.height), &MotionState::STILL, 0)
    }

    /// Renders one frame. `depth` is resampled (nearest) when its size differs from the
    /// sensor's; a map whose buffer does not match its size counts as empty. The same depth
    /// map, motion, `frame_key` and seed always give the same image.
    pub fn render(&self, depth: &DepthMap, motion: &MotionState, frame_key: u64) -> RgbImage {
        let (w, h) = (self.width as usize, self.height as usize);
        let row_len = w * 3;
        let mut bytes = vec![0u8; row_len * h];
        SCRATCH.with(|scratch| {
            let scratch = &mut *scratch.borrow_mut();
            let plan = self.plan(depth, motion, frame_key, &mut scratch.visibility, &mut scratch.visibility_scratch);
            scratch.glow.reset();
            #[cfg(target_arch = "x86_64")]
            if !PORTABLE_ROWS.get() && std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU has AVX2, checked just above.
                unsafe { self.draw_rows_avx2(&plan, motion, &mut bytes, scratch) };
                return;
            }
            self.draw_rows(&plan, motion, &mut bytes, scratch);
        });
        // The buffer has exactly w * h * 3 values by construction.
        RgbImage::from_raw(self.width, self.height, bytes).unwrap_or_else(|| RgbImage::new(self.width, self.height))
    }

    /// [`SensorSim::draw_rows`] compiled for AVX2: the row functions it calls are
    /// `#[inline(always)]`, so they are compiled into it, on four or eight lanes where the
    /// portable code has four (no fused multiply-add, so the arithmetic is the same).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn draw_rows_avx2(&self, plan: &FramePlan, motion: &MotionState, bytes: &mut [u8], scratch: &mut FrameScratch) {
        self.draw_rows(plan, motion, bytes, scratch);
    }

    /// Every pixel row through the stages, into `bytes`.
    #[inline(always)]
    fn draw_rows(&self, plan: &FramePlan, motion: &MotionState, bytes: &mut [u8], scratch: &mut FrameScratch) {
        let FrameScratch { buf, transmit, glow, visibility, motion: blur_scratch, .. } = scratch;
        let (w, h) = (self.width as usize, self.height as usize);
        let row_len = w * 3;
        let style = self.look.markers.map(|m| m.style(look::scale(self.width, self.height)));
        let markers = plan.markers.as_deref().zip(style).map(|(m, style)| MarkerRows::new(m, w, h, style));
        let mut rows = RowWork { transmit, sampler: glow, visibility, markers };
        match plan.blur_px {
            Some(len) => {
                buf.clear();
                buf.extend_from_slice(&self.fixed.background);
                for (y, row) in buf.chunks_exact_mut(row_len).enumerate() {
                    self.compose_row(plan, y, row, &mut rows);
                }
                self.timed(Stage::MotionBlur, || {
                    stages::contact_motion_blur(buf, &self.fixed.rest_frame, w, h, len, motion.direction_rad, blur_scratch)
                });
                for (y, (row, out)) in buf.chunks_exact_mut(row_len).zip(bytes.chunks_exact_mut(row_len)).enumerate() {
                    self.finish_row(plan, y, row, out);
                }
            }
            None => {
                buf.clear();
                buf.resize(row_len, 0.0);
                let lines = self.fixed.background.chunks_exact(row_len).zip(bytes.chunks_exact_mut(row_len));
                for (y, (background, out)) in lines.enumerate() {
                    buf.copy_from_slice(background);
                    self.compose_row(plan, y, buf, &mut rows);
                    self.finish_row(plan, y, buf, out);
                }
            }
        }
    }

    /// The per-frame work of the stages, before any pixel row: the coarse fields, the markers'
    /// positions, the see-through visibility band (into `visibility`). Counts each active stage.
    fn plan(&self, depth: &DepthMap, motion: &MotionState, frame_key: u64, visibility: &mut RowBand, scratch: &mut RowBand) -> FramePlan {
        let s = look::scale(self.width, self.height);
        let depth = self.fit_depth(depth);
        let cell = (CELL_PX * s).round().max(1.0) as usize;
        // Every positive height is also near the skin for see-through: one scan finds the rows
        // both look at.
        let near_rows = stages::near_rows(&depth, optics::SEE_THROUGH_GAP_MM);
        let raw = CellField::indentation(&depth, cell, near_rows.clone());
        let touching = raw.max() > 0.0;
        let skin = &self.skin;
        let spread_px = skin.spread_mm * self.px_per_mm;

        // The indentation: the skin's deformed surface, the dent and the skin dragged in
        // around it.
        let mut indent = raw.clone();
        // Without the stage, `indent` stays the object's dent: the skin follows it only.
        self.stage(Stage::ContactDeformation, || stages::contact_deformation(&mut indent, spread_px, skin.spread_gain));

        let mut markers = self.fixed.markers.clone();
        let mut warp = None;
        if self.look.markers.is_some() {
            self.stage(Stage::MarkerDisplacement, || {
                if !touching {
                    return;
                }
                // Without the elastic spread the skin moves only right at the dent.
                let spread_px = if self.runs(Stage::ContactDeformation) { spread_px } else { cell as f32 };
                // The skin moves with the object's own dent, smoothed by the skin; the broad
                // skirt of the deformation field (which shades) would drag pins far away.
                let u = stages::displacement_field(
                    &raw,
                    spread_px,
                    0.5 * look::RING_PITCH_PX * s,
                    self.px_per_mm,
                    skin.lateral_mm,
                    skin.max_travel_mm,
                );
                if self.fixed.measured {
                    warp = Some(u);
                } else {
                    stages::marker_displacement(&mut markers, &u);
                }
            });
        }

        let mut see_through = None;
        if self.look.object_rgb.is_some() {
            self.stage(Stage::SeeThrough, || {
                // The glow follows the deformed skin: a deeper press lights more of it, further
                // out. Lit by the object's dent alone it keeps the contact's edge sharper, but
                // barely changes with depth (`rig eval --downstream` on the depth plan of the
                // guide: ViTac Z R² -0.26 against 0.92 this way).
                let mut near = indent.clone();
                for v in &mut near.v {
                    *v = skin.glow_source(*v);
                }
                let mut glow = near.clone();
                if touching {
                    let cells = |px: f32| ((px * s) / cell as f32).round().max(1.0) as usize;
                    near.blur(cells(optics::GLOW_NEAR_PX), 2);
                    glow.blur(cells(optics::GLOW_FAR_PX), 3);
                    for (g, n) in glow.v.iter_mut().zip(&near.v) {
                        *g = (1.0 - (-(2.5 * n + 3.5 * *g)).exp()).min(1.0);
                    }
                }
                // The outline softens as the skin wraps the object's edges, more the deeper
                // the press.
                let press_mm = raw.max().min(optics::DEEPEST_EDGE_PRESS_MM);
                let edge_px = optics::SEE_THROUGH_BLUR_PX * s + skin.edge_mm_per_mm * press_mm * self.px_per_mm;
                let seen = stages::visibility(&depth, optics::SEE_THROUGH_GAP_MM, edge_px, skin, near_rows.clone(), visibility, scratch);
                see_through = Some((glow, seen));
            });
        }

        let mut shading = None;
        self.stage(Stage::Shading, || {
            shading = Some(stages::shading_factor(&indent, self.px_per_mm, optics::LIGHT, self.look.shading_gain));
        });
        let mut blur_px = None;
        self.stage(Stage::MotionBlur, || {
            // A streak under half a pixel blurs nothing.
            blur_px = Some(motion.streak_px().min(self.scene.max_blur_px)).filter(|&len| len >= 0.5);
        });
        let mut vignette = false;
        self.stage(Stage::Vignetting, || vignette = true);
        let mut noise_key = None;
        self.stage(Stage::Noise, || noise_key = Some(stages::mix64(self.seed) ^ frame_key));
        FramePlan {
            cols: raw.columns(self.width as usize),
            warp,
            markers: self.look.markers.filter(|_| !self.fixed.measured).map(|_| markers),
            see_through,
            shading,
            blur_px,
            vignette,
            noise_key,
        }
    }

    /// The stages before motion blur on pixel row `y`: a measured look's skin displacement,
    /// see-through, the markers, shading.
    #[inline(always)]
    fn compose_row(&self, plan: &FramePlan, y: usize, row: &mut [f32], work: &mut RowWork<'_>) {
        let (w, h) = (self.width as usize, self.height as usize);
        if let Some(u) = &plan.warp {
            let t = self.clock();
            stages::warp_skin_row(row, y, &self.fixed.background, w, h, u);
            self.clocked(Stage::MarkerDisplacement, t);
        }
        if let (Some((glow, seen)), Some(object_rgb)) = (&plan.see_through, self.look.object_rgb) {
            let t = self.clock();
            let lum = self.fixed.skin_lum.as_deref().filter(|l| l.len() == w * h);
            let transmit = match lum {
                Some(lum) => {
                    stages::transmit_row(row, &lum[y * w..(y + 1) * w], work.transmit);
                    Some(&work.transmit[..])
                }
                None => None,
            };
            let span = self.fixed.fov_span.get(y).copied().unwrap_or((0, w));
            let vis = if *seen { work.visibility.row(y) } else { None };
            let fov = &self.fixed.fov[y * w..(y + 1) * w];
            stages::see_through_row(row, y, glow, &plan.cols, work.sampler, vis, fov, span, object_rgb, self.look.glow_rgb, transmit);
            self.clocked(Stage::SeeThrough, t);
        }
        if let Some(markers) = work.markers.as_mut() {
            markers.draw(row, y);
        }
        if let Some(factor) = &plan.shading {
            let t = self.clock();
            stages::shade_row(row, y, factor, &plan.cols);
            self.clocked(Stage::Shading, t);
        }
    }

    /// The stages after motion blur on pixel row `y` (vignetting, noise), then its bytes into
    /// `out`.
    #[inline(always)]
    fn finish_row(&self, plan: &FramePlan, y: usize, row: &mut [f32], out: &mut [u8]) {
        let w = self.width as usize;
        if plan.vignette {
            let t = self.clock();
            stages::vignetting(row, &self.fixed.vignette[y * w..(y + 1) * w]);
            self.clocked(Stage::Vignetting, t);
        }
        if let Some(key) = plan.noise_key {
            let t = self.clock();
            stages::noise(row, y * w, self.scene.noise_sigma_levels, key);
            self.clocked(Stage::Noise, t);
        }
        stages::to_bytes(row, out);
    }

    /// The depth map at the sensor's size (nearest-neighbour resampling when it differs).
    fn fit_depth<'a>(&self, depth: &'a DepthMap) -> Cow<'a, DepthMap> {
        let valid = depth.height_mm.len() == depth.width as usize * depth.height as usize;
        if valid && depth.width == self.width && depth.height == self.height {
            return Cow::Borrowed(depth);
        }
        let mut out = DepthMap::empty(self.width, self.height);
        if !valid || depth.width == 0 || depth.height == 0 {
            return Cow::Owned(out);
        }
        for y in 0..self.height {
            let sy = (y as u64 * depth.height as u64 / self.height as u64) as u32;
            for x in 0..self.width {
                let sx = (x as u64 * depth.width as u64 / self.width as u64) as u32;
                if let Some(v) = depth.get(sx, sy) {
                    out.height_mm[(y * self.width + x) as usize] = v;
                }
            }
        }
        Cow::Owned(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kind_names() {
        for k in SensorKind::ALL {
            assert_eq!(k.to_string().parse::<SensorKind>().unwrap(), k);
            assert_eq!(k.label().parse::<SensorKind>().unwrap(), k);
        }
        assert_eq!("VITACTIP".parse::<SensorKind>().unwrap(), SensorKind::ViTacTip);
        assert_eq!(SensorKind::ViTac.to_string(), "vitac");
        assert!("gelsight".parse::<SensorKind>().is_err());
    }

    #[test]
    fn mismatched_depth_is_resampled_and_broken_depth_is_empty() {
        let sim = SensorSim::new(SensorKind::ViTac, Scene::preset("minimal").unwrap(), 64, 64, 4.0, 1);
        let broken = DepthMap { width: 64, height: 64, height_mm: vec![1.0; 10] };
        assert_eq!(sim.render(&broken, &MotionState::STILL, 0), sim.reference());
        let small = DepthMap { width: 8, height: 8, height_mm: vec![1.0; 64] };
        assert_ne!(sim.render(&small, &MotionState::STILL, 0), sim.reference());
    }
}

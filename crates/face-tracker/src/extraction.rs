//! Sparse template extraction from the face sub-image at t0 (section 3 of the face paper):
//!
//! - gray-level extrema: pixels brighter (or darker) than all 8 neighbours in a lightly smoothed
//!   image, taken brightest and darkest first;
//! - boundary dipoles: pairs of points on either side of a zero-crossing of the
//!   Laplacian-of-Gaussian image, taken in order of the gray-level step |ΔI| across them;
//!
//! both with a minimum separation between chosen points, inside the ellipse inscribed in the face
//! rectangle and outside the eyes where their outlines are known ([`eye_outlines`]). Each point
//! gets its model position and normal from the [`FaceModel`] and its gray level J from the frame.

use crate::error::FaceError;
use crate::image::{FloatImage, GrayImage, Image, Level};
use crate::landmarks::ibug68;
use crate::lens::Lens;
use crate::model::FaceModel;
use crate::template::{FeaturePoint, MIN_GRAY, Template};
use crate::view::View;

/// A face rectangle in frame pixels: top-left corner and size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaceRect {
    pub x: f32,
    pub y: f32,
    pub width: f32,
    pub height: f32,
}

/// `x,y,width,height`, as a user writes a rectangle (`--face`, faces.csv).
impl std::fmt::Display for FaceRect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{},{},{},{}", self.x, self.y, self.width, self.height)
    }
}

impl FaceRect {
    pub fn centre(&self) -> (f32, f32) {
        (self.x + self.width / 2.0, self.y + self.height / 2.0)
    }

    /// Checks that the rectangle has a size and lies inside the frame.
    pub fn validate(&self, frame: &GrayImage) -> Result<(), FaceError> {
        let names = ["x", "y", "width", "height"];
        let values = [self.x, self.y, self.width, self.height];
        if let Some((name, value)) = names.iter().zip(values).find(|(_, v)| !v.is_finite()) {
            return Err(FaceError::InvalidInput(format!(
                "the face rectangle {self} has {name} {value}: its values must be finite numbers"
            )));
        }
        if self.width < 8.0 || self.height < 8.0 {
            return Err(FaceError::InvalidInput(format!(
                "a face rectangle must be at least 8x8 pixels, got {self} (x,y,width,height)"
            )));
        }
        if self.x < 0.0
            || self.y < 0.0
            || self.x + self.width > frame.width as f32
            || self.y + self.height > frame.height as f32
        {
            return Err(FaceError::InvalidInput(format!(
                "the face rectangle {self} (x,y,width,height) is not inside the {}x{} frame",
                frame.width, frame.height
            )));
        }
        Ok(())
    }
}

/// How a template is extracted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExtractionConfig {
    /// Feature points in all at most (the paper used about 230).
    pub max_points: usize,
    /// A face takes at most this many points per pixel of its rectangle's width (and at most
    /// `max_points`); `None` (the default): always `max_points`. On the synthetic heads one
    /// point per pixel of width tracks better at every width measured, 50 to 120 px (80 px:
    /// 3.2° against 22–27° with 230 points); on the real clips it loses pitch and yaw
    /// (carphone's 60 px face: the yaw's spread 2.5 times the mesh's, against 1.1), so it is
    /// not the default (docs/ACCURACY.md, "Small faces").
    pub points_per_width: Option<f32>,
    /// The share of them that are gray-level extrema; the rest are dipole ends.
    pub extrema_share: f32,
    /// The smallest distance between two chosen points (pixels, at least 1).
    pub separation: f32,
    /// σ of the smoothing before the extrema test and of the LoG (pixels).
    pub sigma: f32,
    /// Each dipole end lies this far from its zero-crossing (pixels).
    pub dipole_half_length: f32,
    /// Dipoles whose gray-level step is below this are ignored.
    pub min_step: f32,
    /// No point is taken inside either eye's fitted outline grown by this factor (at least 1, so
    /// that the whole eye is left out) about its centre (`None`: eyes are taken like the rest). An eye changes on its own, not with the
    /// head (it blinks, narrows in a laugh, turns with the gaze), and the fit reads those
    /// changes as moves of the head. Needs the face's landmarks, so it applies to personalised
    /// templates only.
    pub eye_outline_growth: Option<f32>,
    /// A face rectangle narrower than this many pixels has its landmarks fitted and its template
    /// extracted in its region enlarged by a whole factor (at least 2, at most 4) that brings it
    /// to this width, and the template scaled back to the frame (`enlarge::Enlarged`): the
    /// extraction's pixel scale and the landmark fit then see a small face as they see a larger
    /// one. `None`: every face is taken at its own size.
    pub enlarge_below: Option<f32>,
}

/// A closed polygon in frame pixels, its vertices in order.
pub type Outline = Vec<[f32; 2]>;

impl Default for ExtractionConfig {
    fn default() -> Self {
        Self {
            max_points: 230,
            points_per_width: None,
            extrema_share: 0.35,
            separation: 3.0,
            sigma: 1.2,
            dipole_half_length: 2.0,
            min_step: 6.0,
            // Chosen on real clips against MediaPipe's face mesh (docs/ACCURACY.md, "The eyes"):
            // 1.3 clears the iris and the white without reaching the brows.
            eye_outline_growth: Some(1.3),
            // Chosen on real clips made small (docs/ACCURACY.md, "Small faces"): a face
            // narrower than about 57 px of detector box gets its pitch and yaw back enlarged
            // to 70-90 px; carphone's 48 px face enlarged lost some of its pitch, so a face
            // that wide is taken as it is.
            enlarge_below: Some(46.0),
        }
    }
}

impl ExtractionConfig {
    /// The points a template of a face rectangle `width` pixels wide takes at most: `max_points`,
    /// or fewer by `points_per_width` (at least one).
    pub fn points_for_width(&self, width: f32) -> usize {
        match self.points_per_width {
            Some(per_pixel) => {
                let by_width = (per_pixel * width).round().max(1.0) as usize;
                self.max_points.min(by_width)
            }
            None => self.max_points,
        }
    }
}

/// A separable Gaussian blur (radius 3σ, borders clamped).
pub fn gaussian_blur<T: Level>(image: &Image<T>, sigma: f32) -> FloatImage {
    let radius = (3.0 * sigma).ceil().max(1.0) as i64;
    let weights: Vec<f32> = (-radius..=radius)
        .map(|k| (-(k * k) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let total: f32 = weights.iter().sum();
    let (w, h) = (image.width as i64, image.height as i64);
    let pass = |src: &[f32], horizontal: bool| -> Vec<f32> {
        (0..w * h)
            .map(|k| {
                let (x, y) = (k % w, k / w);
                let mut acc = 0.0;
                for (i, weight) in weights.iter().enumerate() {
                    let o = i as i64 - radius;
                    let (sx, sy) = if horizontal {
                        ((x + o).clamp(0, w - 1), y)
                    } else {
                        (x, (y + o).clamp(0, h - 1))
                    };
                    acc += weight * src[(sy * w + sx) as usize];
                }
                acc / total
            })
            .collect()
    };
    let levels: Vec<f32> = image.data.iter().map(|v| v.level()).collect();
    let data = pass(&pass(&levels, true), false);
    FloatImage {
        width: image.width,
        height: image.height,
        data,
    }
}

/// The 4-neighbour Laplacian of an image (zero on the border).
fn laplacian(image: &FloatImage) -> Vec<f32> {
    let (w, h) = (image.width, image.height);
    (0..w * h)
        .map(|k| {
            let (x, y) = (k % w, k / w);
            if x == 0 || y == 0 || x == w - 1 || y == h - 1 {
                return 0.0;
            }
            image.at(x - 1, y) + image.at(x + 1, y) + image.at(x, y - 1) + image.at(x, y + 1)
                - 4.0 * image.at(x, y)
        })
        .collect()
}

/// A candidate: the points it adds and its priority (larger first).
struct Candidate {
    points: Vec<(f32, f32)>,
    priority: f32,
}

/// Gray-level extrema inside `inside`, brightest and darkest first (priority: distance of the
/// gray level from the extreme it is, so a bright maximum and a dark minimum rank alike).
fn extrema(smooth: &FloatImage, inside: &dyn Fn(f32, f32) -> bool) -> Vec<Candidate> {
    let mut out = Vec::new();
    for y in 1..smooth.height - 1 {
        for x in 1..smooth.width - 1 {
            if !inside(x as f32, y as f32) {
                continue;
            }
            let c = smooth.at(x, y);
            let mut is_max = true;
            let mut is_min = true;
            for (dx, dy) in [
                (-1i32, -1i32),
                (0, -1),
                (1, -1),
                (-1, 0),
                (1, 0),
                (-1, 1),
                (0, 1),
                (1, 1),
            ] {
                let n = smooth.at((x as i32 + dx) as u32, (y as i32 + dy) as u32);
                is_max &= c > n;
                is_min &= c < n;
            }
            if is_max || is_min {
                out.push(Candidate {
                    points: vec![(x as f32, y as f32)],
                    priority: if is_max { c } else { 255.0 - c },
                });
            }
        }
    }
    out
}

/// Boundary dipoles across the LoG's zero-crossings between horizontal and vertical neighbours,
/// by the gray-level step across their ends.
fn dipoles(
    smooth: &FloatImage,
    config: &ExtractionConfig,
    inside: &dyn Fn(f32, f32) -> bool,
) -> Vec<Candidate> {
    let lap = laplacian(smooth);
    let (w, h) = (smooth.width, smooth.height);
    let d = config.dipole_half_length;
    let mut out = Vec::new();
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let here = lap[(y * w + x) as usize];
            for (dx, dy) in [(1u32, 0u32), (0, 1)] {
                let (nx, ny) = (x + dx, y + dy);
                if nx >= w - 1 || ny >= h - 1 {
                    continue;
                }
                let there = lap[(ny * w + nx) as usize];
                if here * there >= 0.0 {
                    continue;
                }
                let (cx, cy) = (x as f32 + dx as f32 / 2.0, y as f32 + dy as f32 / 2.0);
                let (ax, ay) = (cx - dx as f32 * d, cy - dy as f32 * d);
                let (bx, by) = (cx + dx as f32 * d, cy + dy as f32 * d);
                if !(inside(ax, ay) && inside(bx, by)) {
                    continue;
                }
                let (Some(ia), Some(ib)) = (smooth.bilinear(ax, ay), smooth.bilinear(bx, by))
                else {
                    continue;
                };
                let step = (ia - ib).abs();
                if step >= config.min_step {
                    out.push(Candidate {
                        points: vec![(ax, ay), (bx, by)],
                        priority: step,
                    });
                }
            }
        }
    }
    out
}

/// Candidates sorted by priority, largest first.
fn by_priority(mut candidates: Vec<Candidate>) -> Vec<Candidate> {
    candidates.sort_by(|a, b| b.priority.total_cmp(&a.priority));
    candidates
}

/// The two eyes' outlines in a face's 68 landmarks (frame pixels), each grown by `growth` about
/// its centre: the regions a template avoids with [`ExtractionConfig::eye_outline_growth`].
pub fn eye_outlines(landmarks: &[[f32; 2]], growth: f32) -> Vec<Outline> {
    if landmarks.len() != ibug68::COUNT {
        return Vec::new();
    }
    [ibug68::RIGHT_EYE, ibug68::LEFT_EYE]
        .into_iter()
        .map(|eye| {
            let outline = &landmarks[eye];
            let n = outline.len() as f32;
            let centre = outline
                .iter()
                .fold([0.0, 0.0], |c, p| [c[0] + p[0] / n, c[1] + p[1] / n]);
            (outline.iter())
                .map(|p| {
                    [
                        centre[0] + growth * (p[0] - centre[0]),
                        centre[1] + growth * (p[1] - centre[1]),
                    ]
                })
                .collect()
        })
        .collect()
}

/// Whether (x, y) lies inside `outline` (even-odd rule: a crossing count of the ray to +x).
pub fn inside_outline(outline: &[[f32; 2]], x: f32, y: f32) -> bool {
    let mut inside = false;
    let mut previous = match outline.last() {
        Some(&p) => p,
        None => return false,
    };
    for &p in outline {
        if (p[1] > y) != (previous[1] > y)
            && x < (previous[0] - p[0]) * (y - p[1]) / (previous[1] - p[1]) + p[0]
        {
            inside = !inside;
        }
        previous = p;
    }
    inside
}

/// Greedy selection in (already sorted) priority order: a candidate is taken when all its points
/// are at least `separation` from every point taken so far, until `budget` points are taken.
fn select(candidates: &[Candidate], taken: &mut Vec<(f32, f32)>, budget: usize, separation: f32) {
    let limit = taken.len() + budget;
    let sep2 = separation * separation;
    for c in candidates {
        if taken.len() + c.points.len() > limit {
            continue;
        }
        let clear = c.points.iter().all(|&(x, y)| {
            taken
                .iter()
                .all(|&(tx, ty)| (tx - x).powi(2) + (ty - y).powi(2) >= sep2)
        });
        if clear {
            taken.extend(&c.points);
        }
    }
}

/// The template of the face in `rect` of `frame`, the face taken as looking straight at the
/// camera (no landmarks: no region is avoided).
pub fn extract_template(
    frame: &GrayImage,
    rect: &FaceRect,
    model: &FaceModel,
    config: &ExtractionConfig,
) -> Result<Template, FaceError> {
    extract_template_seen(
        frame,
        rect,
        model,
        config,
        &View::frontal(),
        &Lens::WEAK,
        &[],
    )
}

/// The template of the face in `rect` of `frame` seen with `view`: each chosen pixel's point is
/// where the model, turned and scaled by the view, shows it (in the model's units), and pixels
/// whose ray misses the model or meets it facing away are not taken, nor pixels inside any of
/// `avoid` (frame pixels; the eyes' outlines, [`eye_outlines`]). The face is seen through `lens`
/// ([`Lens::WEAK`]: the paper's weak perspective), the rectangle's centre its centre.
pub fn extract_template_seen(
    frame: &GrayImage,
    rect: &FaceRect,
    model: &FaceModel,
    config: &ExtractionConfig,
    view: &View,
    lens: &Lens,
    avoid: &[Outline],
) -> Result<Template, FaceError> {
    rect.validate(frame)?;
    if config.max_points == 0
        || config
            .points_per_width
            .is_some_and(|p| !(p.is_finite() && p > 0.0))
        || !(0.0..=1.0).contains(&config.extrema_share)
        || !(config.separation >= 1.0 && config.sigma > 0.0 && config.dipole_half_length > 0.0)
        || config
            .eye_outline_growth
            .is_some_and(|g| !(g.is_finite() && g >= 1.0))
        || config
            .enlarge_below
            .is_some_and(|w| !(w.is_finite() && w >= 0.0))
    {
        return Err(FaceError::InvalidInput(format!(
            "invalid extraction settings: {config:?}"
        )));
    }
    let (cx, cy) = rect.centre();
    let (hw, hh) = (rect.width / 2.0, rect.height / 2.0);
    let to_model = |x: f32, y: f32| ((x - cx) / hw, (y - cy) / hh);
    let inside = |x: f32, y: f32| {
        let (u, v) = to_model(x, y);
        u * u + v * v <= 0.9 && !avoid.iter().any(|outline| inside_outline(outline, x, y))
    };
    let smooth = gaussian_blur(frame, config.sigma);
    let max_points = config.points_for_width(rect.width);
    let extrema_budget = (max_points as f32 * config.extrema_share).round() as usize;
    let mut taken = Vec::with_capacity(max_points);
    let extrema = by_priority(extrema(&smooth, &inside));
    select(&extrema, &mut taken, extrema_budget, config.separation);
    let left = max_points - taken.len();
    select(
        &by_priority(dipoles(&smooth, config, &inside)),
        &mut taken,
        left,
        config.separation,
    );
    // Fill with more extrema if the dipoles ran short (those taken already are within the
    // separation of themselves, so none is taken twice).
    let left = max_points - taken.len();
    if left > 0 {
        select(&extrema, &mut taken, left, config.separation);
    }
    let points = taken
        .into_iter()
        .filter_map(|(x, y)| {
            let gray = frame.bilinear(x, y)?;
            let (point, normal) =
                view.cast_through(lens, [cx, cy], model, (hw, hh), [x - cx, y - cy])?;
            Some(FeaturePoint::new(point, normal, gray.max(MIN_GRAY)))
        })
        .collect();
    Template::new(points).map_err(|_| {
        FaceError::InvalidInput(format!(
            "no feature points in the face rectangle {rect} (x,y,width,height): the region is flat (no gray-level extrema or edges)"
        ))
    })
}

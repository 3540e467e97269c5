//! Identities: the person a track follows, kept when the face is lost and found again. Tracks
//! are numbered in the order faces are found and a lost track's number is never reused; an
//! identity outlives its track. When a new track starts, the templates of the identities whose
//! tracks have ended are fitted to the new face (a search over its position, size, yaw and
//! contrast about the detection); the one that fits best takes the track, if it fits the face
//! well enough, else the track starts a new identity.
//!
//! "Well enough" is measured against the templates themselves: a stored template must fit the
//! new face within [`IdentityConfig::match_share`] of the smaller of the two templates' ε a
//! quarter of a face off their faces (`FaceTracker::off_face_error`), so that a faint or small
//! face, whose template fits anything smooth, is not matched; and it must fit at most
//! [`IdentityConfig::distinct_share`] of the next best person's ε. On the identity scenario's
//! heads a person's own template fitted them 1.4 to 46 times better than any other's
//! (docs/ACCURACY.md, "Identities").

use std::collections::BTreeMap;

use crate::extraction::FaceRect;
use crate::image::GrayImage;
use crate::lens::Lens;
use crate::likelihood::{least_squares_gain, residual_error_through};
use crate::projection::{ALPHA, DIMS, SCALE};
use crate::template::Template;

/// How identities are matched.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IdentityConfig {
    /// A stored template matches a new face when its best ε there is at most this share of
    /// the smaller of the two templates' ε off their faces...
    pub match_share: f64,
    /// ... and at most this share of the next best person's ε there (when another person's
    /// track has ended too): a match must stand out.
    pub distinct_share: f64,
    /// A face found again near where a track was lost a moment ago is that track's person when
    /// the person's template fits it within this share of the two templates' ε off their
    /// faces (better than background): the place and the moment are most of the evidence.
    /// Measured on wolfgang's clip: his template fitted his face found again after a hand had
    /// passed at 0.52 of it, where the strict match needs 0.1.
    pub continuity_share: f64,
}

impl Default for IdentityConfig {
    fn default() -> Self {
        Self {
            match_share: 0.1,
            distinct_share: 0.5,
            continuity_share: 0.75,
        }
    }
}

/// A person seen so far: the template their first track started from (taken near frontal,
/// where the detector finds faces) and the width of its rectangle.
#[derive(Debug, Clone)]
struct Person {
    template: Template,
    width: f32,
    /// Its template's ε off its face where it was taken.
    off_face_error: f64,
    /// The running track that follows this person, if any.
    track: Option<usize>,
}

/// The identities of a run's tracks.
#[derive(Debug, Clone, Default)]
pub struct Identities {
    config: IdentityConfig,
    people: Vec<Person>,
    of_track: BTreeMap<usize, usize>,
}

/// A new face to identify: the frame its template was taken from, its rectangle there, its
/// template and that template's ε off its face.
pub struct NewFace<'a> {
    pub frame: &'a GrayImage,
    pub rect: &'a FaceRect,
    pub template: &'a Template,
    pub off_face_error: f64,
}

impl Identities {
    pub fn new(config: IdentityConfig) -> Self {
        Self {
            config,
            people: Vec::new(),
            of_track: BTreeMap::new(),
        }
    }

    /// The identity of new track `track` on `face`: a person whose track has ended, if their
    /// template fits the face well enough (the best fitting), else a new person.
    pub fn start(&mut self, track: usize, face: &NewFace<'_>, lens: &Lens) -> usize {
        let share = self.config.match_share;
        let mut fits: Vec<(usize, f64, f64)> = (self.people.iter().enumerate())
            .filter(|(_, person)| person.track.is_none())
            .map(|(id, person)| {
                // Both templates' scales: a smooth template (a small or blurred face) fits
                // anything smooth with a small ε, and must fit far better than that to match.
                let threshold = share * face.off_face_error.min(person.off_face_error);
                (id, best_fit(person, face, lens), threshold)
            })
            .collect();
        fits.sort_by(|a, b| a.1.total_cmp(&b.1));
        let stands_out = |best: f64| {
            (fits.get(1)).is_none_or(|next| best <= self.config.distinct_share * next.1)
        };
        let best = (fits.first().copied())
            .filter(|&(_, error, threshold)| error <= threshold && stands_out(error));
        let id = match best {
            Some((id, _, _)) => id,
            None => {
                self.people.push(Person {
                    template: face.template.clone(),
                    width: face.rect.width,
                    off_face_error: face.off_face_error,
                    track: None,
                });
                self.people.len() - 1
            }
        };
        self.assign(track, id)
    }

    /// Person `id` is followed by track `track` from now on; their identity.
    fn assign(&mut self, track: usize, id: usize) -> usize {
        self.people[id].track = Some(track);
        self.of_track.insert(track, id);
        id
    }

    /// The identity of new track `track` on `face`, found again near where track `lost` was lost
    /// a moment ago: `lost`'s person when their track has ended and their template fits the
    /// face within [`IdentityConfig::continuity_share`] of background, else as [`Self::start`].
    pub fn start_found_again(
        &mut self,
        track: usize,
        face: &NewFace<'_>,
        lens: &Lens,
        lost: usize,
    ) -> usize {
        match self.continued(lost, face, lens) {
            Some(id) => self.assign(track, id),
            None => self.start(track, face, lens),
        }
    }

    /// The person of lost track `lost` if `face` may be them found again.
    fn continued(&self, lost: usize, face: &NewFace<'_>, lens: &Lens) -> Option<usize> {
        let &id = self.of_track.get(&lost)?;
        let person = self.people.get(id).filter(|p| p.track.is_none())?;
        let threshold =
            self.config.continuity_share * face.off_face_error.min(person.off_face_error);
        (best_fit(person, face, lens) <= threshold).then_some(id)
    }

    /// Track `track` has ended: its person may be found again.
    pub fn end(&mut self, track: usize) {
        if let Some(&id) = self.of_track.get(&track) {
            self.people[id].track = None;
        }
    }

    /// The identity of track `track` (started with [`Self::start`]).
    pub fn of(&self, track: usize) -> Option<usize> {
        self.of_track.get(&track).copied()
    }

    /// People seen so far.
    pub fn len(&self) -> usize {
        self.people.len()
    }

    pub fn is_empty(&self) -> bool {
        self.people.is_empty()
    }
}

/// The least ε of `person`'s template on the new face ([`fit_template_at`]).
fn best_fit(person: &Person, face: &NewFace<'_>, lens: &Lens) -> f64 {
    fit_template_at(
        (&person.template, person.width),
        face.frame,
        face.rect,
        lens,
    )
    .0
}

/// Starting scales of the pose search, as shares of the one the rectangle's width gives: a
/// detector's square frames a face larger or smaller than its tracked rectangle, and the search
/// found the scale 0.81–1.0 times the rectangle's on the identity scenario's heads.
const START_SCALES: [f32; 4] = [0.8, 0.9, 1.0, 1.1];

/// The best starts refined by the local search.
const STARTS_REFINED: usize = 3;

/// The least ε of a template (taken on a face `width` pixels wide) on the face at `rect` of
/// `frame`, and the state it is reached at. Starts: each of 27 rotations (pitch, yaw and roll
/// each −0.2, 0 or 0.2 rad) at each of [`START_SCALES`] about the rectangle's centre, each with
/// the contrast α that fits it in least squares (the light changes between the template's frame
/// and this one: the scenario's heads needed α 1.1–1.4, where a start at α = 1 stayed in a
/// local minimum at ε 0.03 against 0.003); the [`STARTS_REFINED`] best refined by [`refine`].
/// Used for identities, and for a running track's template to tell whether it has drifted off
/// its face, and where to (`crate::auto`).
pub(crate) fn fit_template_at(
    (template, width): (&Template, f32),
    frame: &GrayImage,
    rect: &FaceRect,
    lens: &Lens,
) -> (f64, [f32; DIMS]) {
    let (cx, cy) = rect.centre();
    let scale = rect.width / width;
    let fit = |state: &[f32; DIMS]| residual_error_through(state, template, frame, lens);
    let turns = [-0.2f32, 0.0, 0.2];
    let mut starts = Vec::with_capacity(27 * START_SCALES.len());
    for share in START_SCALES {
        for rx in turns {
            for ry in turns {
                for rz in turns {
                    let mut state = [cx, cy, scale * share, rx, ry, rz, 1.0];
                    state[ALPHA] = least_squares_gain(&state, template, frame, lens)
                        .filter(|gain| gain.is_finite())
                        .map_or(1.0, |gain| gain.clamp(MIN_START_GAIN, MAX_START_GAIN));
                    starts.push((fit(&state), state));
                }
            }
        }
    }
    starts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let steps = search_steps(rect.width, scale);
    (starts.iter().take(STARTS_REFINED))
        .map(|&(_, state)| refine(state, steps, &fit))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .unwrap_or((f64::INFINITY, [cx, cy, scale, 0.0, 0.0, 0.0, 1.0]))
}

/// The least ε of `template` on `frame` by [`refine`]'s local search from `state`, where the
/// face is `face_width` pixels wide ([`search_steps`], as in [`fit_template_at`]), and the
/// state it is reached at: for a track whose pose is known, where it may be (`crate::auto`).
pub(crate) fn refine_template_at(
    template: &Template,
    frame: &GrayImage,
    lens: &Lens,
    state: [f32; DIMS],
    face_width: f32,
) -> (f64, [f32; DIMS]) {
    let fit = |s: &[f32; DIMS]| residual_error_through(s, template, frame, lens);
    refine(state, search_steps(face_width, state[SCALE]), &fit)
}

/// The local search's first steps for a face `face_width` pixels wide at scale `scale`: a
/// tenth of the face in position, 8 % of the scale, 0.1 rad of each turn, 0.15 of α.
fn search_steps(face_width: f32, scale: f32) -> [f32; DIMS] {
    let shift = face_width / 10.0;
    [shift, shift, 0.08 * scale, 0.1, 0.1, 0.1, 0.15]
}

/// The starting α stays within what the tracker's state allows.
const MIN_START_GAIN: f32 = 0.25;
const MAX_START_GAIN: f32 = 4.0;

/// A local search from `state`: each value in turn moved a step either way while that fits
/// better, then the steps halved, four times. The least ε and its state.
fn refine(
    mut state: [f32; DIMS],
    mut steps: [f32; DIMS],
    fit: &impl Fn(&[f32; DIMS]) -> f64,
) -> (f64, [f32; DIMS]) {
    let mut best = fit(&state);
    for _ in 0..4 {
        for _pass in 0..8 {
            let mut improved = false;
            for d in 0..DIMS {
                for sign in [-1.0f32, 1.0] {
                    let mut moved = state;
                    moved[d] += sign * steps[d];
                    let error = fit(&moved);
                    if error < best {
                        (best, state, improved) = (error, moved, true);
                    }
                }
            }
            if !improved {
                break;
            }
        }
        steps.iter_mut().for_each(|s| *s /= 2.0);
    }
    (best, state)
}

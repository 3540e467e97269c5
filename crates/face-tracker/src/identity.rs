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
use crate::likelihood::residual_error_through;
use crate::projection::DIMS;
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
}

impl Default for IdentityConfig {
    fn default() -> Self {
        Self {
            match_share: 0.1,
            distinct_share: 0.5,
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
        self.people[id].track = Some(track);
        self.of_track.insert(track, id);
        id
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

/// The least ε of `person`'s template on the new face: from each of 27 starting rotations
/// (pitch, yaw and roll each −0.2, 0 or 0.2 rad) about the face's rectangle (its centre, its
/// size relative to the person's first rectangle, α = 1), the best of them refined by
/// [`refine`].
fn best_fit(person: &Person, face: &NewFace<'_>, lens: &Lens) -> f64 {
    fit_template_at(
        (&person.template, person.width),
        face.frame,
        face.rect,
        lens,
    )
    .0
}

/// The least ε of a template (taken on a face `width` pixels wide) on the face at `rect` of
/// `frame`, and the state it is reached at: [`best_fit`]'s search, for any template (a running
/// track's, to tell whether it has drifted off its face, and where to: `crate::auto`).
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
    let mut start = ([cx, cy, scale, 0.0, 0.0, 0.0, 1.0], f64::INFINITY);
    for rx in turns {
        for ry in turns {
            for rz in turns {
                let state = [cx, cy, scale, rx, ry, rz, 1.0];
                let error = fit(&state);
                if error < start.1 {
                    start = (state, error);
                }
            }
        }
    }
    let steps = [
        rect.width / 10.0,
        rect.width / 10.0,
        0.08 * scale,
        0.1,
        0.1,
        0.1,
        0.15,
    ];
    refine(start.0, steps, &fit)
}

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

//! Shows the personalised face model of the face in a photograph: the generic head with its
//! landmarks and triangulation, the photograph with the fitted landmarks, and the warped head
//! (both heads shaded by their normals, lit from the top left).
//!
//! `cargo run --release -p face-tracker --example personalise -- PHOTO OUT.png [CASCADE [MODEL]]`
//! (the first face the Haar detector finds; the cascade defaults to opencv-data's alt2, the
//! landmark model to libdlib-data's).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use face_tracker::detect::{Cascade, DetectConfig};
use face_tracker::landmarks::{DEFAULT_PREDICTOR, ShapePredictor};
use face_tracker::model::FaceModel;
use face_tracker::personal::Personaliser;
use face_tracker::{AutoConfig, FaceError, GrayImage};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [photo, out, rest @ ..] = args.as_slice() else {
        return Err("usage: personalise PHOTO OUT.png [CASCADE [MODEL]]".into());
    };
    let cascade = rest.first().map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from("/usr/share/opencv4/haarcascades/haarcascade_frontalface_alt2.xml")
    });
    let landmark_model = rest
        .get(1)
        .map(PathBuf::from)
        .unwrap_or(PathBuf::from(DEFAULT_PREDICTOR));
    let frame = GrayImage::load(Path::new(photo))?;
    let faces = Cascade::load(&cascade)?.detect(&frame, &DetectConfig::default())?;
    let face = faces.first().ok_or("no face found")?;
    let rect = AutoConfig::default().face_rect(face, &frame);
    let personaliser = Personaliser::new(Arc::new(ShapePredictor::load(&landmark_model)?))?;
    let generic = FaceModel::generic(129)?;
    let personal = personaliser.personalise(&frame, &rect, &generic)?;

    // Panels of twice the face rectangle's size (the model spans it).
    let zoom = 2.0;
    let (w, h) = (
        (zoom * rect.width).round() as u32,
        (zoom * rect.height).round() as u32,
    );
    let shade = |m: &FaceModel| -> Vec<u8> {
        let light = [-0.4f32, -0.5, 0.77];
        (0..w * h)
            .map(|k| {
                let u = -1.0 + 2.0 * (k % w) as f32 / (w - 1) as f32;
                let v = -1.0 + 2.0 * (k / w) as f32 / (h - 1) as f32;
                let (height, n) = m.sample(u, v);
                if height <= 0.0 {
                    return 0;
                }
                let lit = n[0] * light[0] + n[1] * light[1] + n[2] * light[2];
                (40.0 + 200.0 * lit.max(0.0)) as u8
            })
            .collect()
    };
    let mut canvas = image::RgbImage::new(3 * w, h);
    let gray = shade(&generic);
    let warped = shade(&personal.model);
    for y in 0..h {
        for x in 0..w {
            let g = gray[(y * w + x) as usize];
            canvas.put_pixel(x, y, image::Rgb([g, g, g]));
            let f = frame
                .bilinear(rect.x + x as f32 / zoom, rect.y + y as f32 / zoom)
                .unwrap_or(0.0) as u8;
            canvas.put_pixel(w + x, y, image::Rgb([f, f, f]));
            let p = warped[(y * w + x) as usize];
            canvas.put_pixel(2 * w + x, y, image::Rgb([p, p, p]));
        }
    }
    let to_panel = |u: f32, v: f32| {
        (
            (u + 1.0) / 2.0 * (w - 1) as f32,
            (v + 1.0) / 2.0 * (h - 1) as f32,
        )
    };
    let vertices: Vec<(f32, f32)> = personaliser
        .warp_vertices()
        .iter()
        .map(|p| to_panel(p[0], p[1]))
        .collect();
    for t in personaliser.triangles() {
        for e in 0..3 {
            line(
                &mut canvas,
                vertices[t[e]],
                vertices[t[(e + 1) % 3]],
                w,
                [40, 120, 220],
            );
        }
    }
    let generic_pts: Vec<(f32, f32)> = personaliser
        .generic_landmarks()
        .iter()
        .map(|p| to_panel(p[0], p[1]))
        .collect();
    for &(x, y) in &generic_pts {
        dot(&mut canvas, x, y, [255, 60, 60]);
    }
    for p in &personal.landmarks {
        let (x, y) = (zoom * (p[0] - rect.x), zoom * (p[1] - rect.y));
        dot(&mut canvas, w as f32 + x, y, [255, 60, 60]);
        dot(&mut canvas, 2.0 * w as f32 + x, y, [255, 60, 60]);
    }
    canvas
        .save(out)
        .map_err(|e| FaceError::InvalidInput(format!("{out}: {e}")))?;
    println!("face rectangle {rect:?}; wrote {out}");
    Ok(())
}

fn dot(img: &mut image::RgbImage, x: f32, y: f32, color: [u8; 3]) {
    for dy in -1..=1 {
        for dx in -1..=1 {
            let (px, py) = (x.round() as i64 + dx, y.round() as i64 + dy);
            if px >= 0 && py >= 0 && (px as u32) < img.width() && (py as u32) < img.height() {
                img.put_pixel(px as u32, py as u32, image::Rgb(color));
            }
        }
    }
}

/// A line from a to b, drawn where it lies left of `clip`.
fn line(img: &mut image::RgbImage, a: (f32, f32), b: (f32, f32), clip: u32, color: [u8; 3]) {
    let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for s in 0..=steps {
        let t = s as f32 / steps as f32;
        let (x, y) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
        if x >= 0.0 && y >= 0.0 && (x as u32) < clip && (y as u32) < img.height() {
            img.put_pixel(x as u32, y as u32, image::Rgb(color));
        }
    }
}

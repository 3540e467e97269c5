//! `face synth`: a synthetic video written as PNG frames with its rectangles and ground truth.

use super::args::SynthArgs;
use super::{RECTS_FILE, TRUTH_FILE, model};
use crate::run_output::{self};
use anyhow::Context;
use face_tracker::projection::STATE_NAMES;
use face_tracker::synth::{FaceVideoRenderer, face_state, initial_rect};
use std::path::Path;

pub(super) fn write_text(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

pub(super) fn synth(args: &SynthArgs) -> anyhow::Result<()> {
    let config = args.video.config()?;
    let model = model()?;
    run_output::claim_synthetic_dir(&args.out, args.force)?;
    remove_old_frames(&args.out)?;
    let bar = crate::console::progress_bar(config.frames, false);
    let mut truth = String::from("frame,face");
    for n in STATE_NAMES {
        truth.push(',');
        truth.push_str(n);
    }
    truth.push('\n');
    let renderer = FaceVideoRenderer::new(&config, &model)?;
    for frame in 0..config.frames {
        renderer
            .render(frame)?
            .save_png(&args.out.join(format!("frame_{frame:05}.png")))?;
        // A face out of the picture has no row (the reader takes it as unknown).
        for k in (0..config.faces).filter(|&k| config.visible(k, frame)) {
            let s = face_state(&config, k, frame);
            truth.push_str(&format!("{frame},{k}"));
            for v in s {
                truth.push_str(&format!(",{v}"));
            }
            truth.push('\n');
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut rects = String::from("x,y,width,height\n");
    for k in 0..config.faces {
        let r = initial_rect(&config, k);
        rects.push_str(&format!("{},{},{},{}\n", r.x, r.y, r.width, r.height));
    }
    write_text(&args.out.join(RECTS_FILE), &rects)?;
    write_text(&args.out.join(TRUTH_FILE), &truth)?;
    outln!(
        "wrote {} frames of {}x{} with {} faces, faces.csv and ground_truth.csv to {}",
        config.frames,
        config.width,
        config.height,
        config.faces,
        args.out.display()
    );
    Ok(())
}

/// Removes the frames an earlier `face synth` left in `dir` (frame_NNNNN.png), so that the new
/// video is not mixed with the tail of a longer old one; says how many when there were some.
pub(super) fn remove_old_frames(dir: &Path) -> anyhow::Result<()> {
    let mut removed = 0;
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let path = entry
            .with_context(|| format!("reading {}", dir.display()))?
            .path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if name.starts_with("frame_") && name.ends_with(".png") {
            std::fs::remove_file(&path)
                .with_context(|| format!("removing the old frame {}", path.display()))?;
            removed += 1;
        }
    }
    if removed > 0 {
        errln!(
            "note: removed {removed} frames of an earlier video from {}",
            dir.display()
        );
    }
    Ok(())
}

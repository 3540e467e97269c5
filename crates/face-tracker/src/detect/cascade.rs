//! OpenCV's Haar cascade files (the `opencv-cascade-classifier` XML of OpenCV 3 and later, as in
//! `haarcascade_frontalface_alt2.xml`), read into plain structures the detector evaluates.
//!
//! A cascade is a list of boosted stages; a stage passes a window when the sum of its weak
//! classifiers' leaf values reaches the stage threshold. A weak classifier is a small tree:
//! `internalNodes` holds (left, right, feature, threshold) per node, a child ≤ 0 is leaf −child.
//! A feature is two or three weighted rectangles in window coordinates.

use std::path::Path;

use roxmltree::{Document, Node};

use crate::error::{FaceError, file_error};

/// A rectangle of a Haar feature (window coordinates) and its weight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WeightedRect {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
    pub weight: f32,
}

/// A node of a weak classifier's tree: go left when the normalised feature value is below the
/// threshold. A child > 0 is a node index in the same tree, a child ≤ 0 is leaf −child.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TreeNode {
    pub left: i32,
    pub right: i32,
    pub feature: usize,
    pub threshold: f32,
}

#[derive(Debug, Clone, PartialEq)]
pub struct WeakClassifier {
    pub nodes: Vec<TreeNode>,
    pub leaves: Vec<f32>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Stage {
    pub threshold: f32,
    pub classifiers: Vec<WeakClassifier>,
}

/// A Haar cascade: its window size, stages and features.
#[derive(Debug, Clone, PartialEq)]
pub struct Cascade {
    pub width: u32,
    pub height: u32,
    pub stages: Vec<Stage>,
    pub features: Vec<Vec<WeightedRect>>,
}

impl Cascade {
    /// Reads a cascade file.
    pub fn load(path: &Path) -> Result<Self, FaceError> {
        let text = std::fs::read_to_string(path).map_err(|e| file_error(path, e))?;
        Self::parse(&text).map_err(|e| file_error(path, e))
    }

    /// Parses the XML text of a cascade; every index and size is checked.
    pub fn parse(text: &str) -> Result<Self, String> {
        let document = Document::parse(text).map_err(|e| format!("not a valid XML file: {e}"))?;
        let cascade = document
            .descendants()
            .find(|n| n.has_tag_name("cascade"))
            .ok_or("no <cascade> element: not an OpenCV cascade file (OpenCV 3+ format)")?;
        let stage_type = text_of(cascade, "stageType")?;
        let feature_type = text_of(cascade, "featureType")?;
        if stage_type != "BOOST" || feature_type != "HAAR" {
            return Err(format!(
                "only boosted Haar cascades are supported; this one is {stage_type} with {feature_type} features"
            ));
        }
        let width: u32 = number(text_of(cascade, "width")?, "width")?;
        let height: u32 = number(text_of(cascade, "height")?, "height")?;
        if width < 3 || height < 3 {
            return Err(format!("a {width}x{height} window is too small"));
        }
        let features = items(child(cascade, "features")?)
            .enumerate()
            .map(|(i, f)| read_feature(f, width, height).map_err(|e| format!("feature {i}: {e}")))
            .collect::<Result<Vec<_>, _>>()?;
        let stages = items(child(cascade, "stages")?)
            .enumerate()
            .map(|(i, s)| read_stage(s, features.len()).map_err(|e| format!("stage {i}: {e}")))
            .collect::<Result<Vec<_>, _>>()?;
        if stages.is_empty() {
            return Err("the cascade has no stages".into());
        }
        if let Ok(declared) = text_of(cascade, "stageNum") {
            let declared: usize = number(declared, "stageNum")?;
            if declared != stages.len() {
                return Err(format!(
                    "{declared} stages declared, {} found (a truncated file?)",
                    stages.len()
                ));
            }
        }
        Ok(Self {
            width,
            height,
            stages,
            features,
        })
    }
}

fn child<'a, 'i>(node: Node<'a, 'i>, name: &str) -> Result<Node<'a, 'i>, String> {
    node.children()
        .find(|n| n.has_tag_name(name))
        .ok_or_else(|| format!("missing <{name}>"))
}

fn text_of<'a>(node: Node<'a, '_>, name: &str) -> Result<&'a str, String> {
    Ok(child(node, name)?.text().unwrap_or("").trim())
}

/// The `<_>` items of a list element.
fn items<'a, 'i>(node: Node<'a, 'i>) -> impl Iterator<Item = Node<'a, 'i>> {
    node.children().filter(|n| n.has_tag_name("_"))
}

fn number<T: std::str::FromStr>(text: &str, what: &str) -> Result<T, String> {
    text.parse()
        .map_err(|_| format!("{what}: {text:?} is not a valid number"))
}

fn numbers(text: &str, what: &str) -> Result<Vec<f64>, String> {
    text.split_whitespace()
        .map(|t| {
            t.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("{what}: {t:?} is not a finite number"))
        })
        .collect()
}

fn read_feature(node: Node, width: u32, height: u32) -> Result<Vec<WeightedRect>, String> {
    if let Ok(tilted) = text_of(node, "tilted")
        && tilted != "0"
    {
        return Err("tilted (45°) features are not supported".into());
    }
    let rects = items(child(node, "rects")?)
        .map(|r| {
            let v = numbers(r.text().unwrap_or(""), "rectangle")?;
            let [x, y, w, h, weight] = v[..] else {
                return Err(format!("a rectangle needs x y w h weight, got {v:?}"));
            };
            let whole = [x, y, w, h];
            if whole.iter().any(|&c| c < 0.0 || c.fract() != 0.0) {
                return Err(format!("rectangle {whole:?} is not in whole pixels"));
            }
            // Checked in f64: a corrupt file's coordinates can be far beyond u32.
            if w == 0.0 || h == 0.0 || x + w > f64::from(width) || y + h > f64::from(height) {
                return Err(format!(
                    "rectangle ({x}, {y}, {w}, {h}) is empty or outside the {width}x{height} window"
                ));
            }
            let (x, y, w, h) = (x as u32, y as u32, w as u32, h as u32);
            Ok(WeightedRect {
                x,
                y,
                width: w,
                height: h,
                weight: weight as f32,
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    if !(2..=3).contains(&rects.len()) {
        return Err(format!(
            "{} rectangles (a Haar feature has 2 or 3)",
            rects.len()
        ));
    }
    Ok(rects)
}

fn read_stage(node: Node, features: usize) -> Result<Stage, String> {
    let threshold: f64 = numbers(text_of(node, "stageThreshold")?, "stageThreshold")?
        .first()
        .copied()
        .ok_or("empty stageThreshold")?;
    let classifiers = items(child(node, "weakClassifiers")?)
        .enumerate()
        .map(|(i, w)| read_weak(w, features).map_err(|e| format!("weak classifier {i}: {e}")))
        .collect::<Result<Vec<_>, _>>()?;
    if classifiers.is_empty() {
        return Err("no weak classifiers".into());
    }
    Ok(Stage {
        threshold: threshold as f32,
        classifiers,
    })
}

fn read_weak(node: Node, features: usize) -> Result<WeakClassifier, String> {
    let values = numbers(text_of(node, "internalNodes")?, "internalNodes")?;
    let leaves: Vec<f32> = numbers(text_of(node, "leafValues")?, "leafValues")?
        .into_iter()
        .map(|v| v as f32)
        .collect();
    if values.is_empty() || !values.len().is_multiple_of(4) {
        return Err(format!(
            "{} internal-node values (four per node)",
            values.len()
        ));
    }
    let nodes = values
        .chunks_exact(4)
        .enumerate()
        .map(|(i, c)| {
            // Children and the feature are indices: whole numbers (a cast would truncate a
            // fraction and clamp a negative feature to 0 without a word).
            let index = |v: f64| (v.fract() == 0.0 && v.abs() <= f64::from(i32::MAX)).then_some(v);
            match (index(c[0]), index(c[1]), index(c[2])) {
                (Some(left), Some(right), Some(feature)) if feature >= 0.0 => Ok(TreeNode {
                    left: left as i32,
                    right: right as i32,
                    feature: feature as usize,
                    threshold: c[3] as f32,
                }),
                _ => Err(format!(
                    "node {i}: children and feature must be whole numbers (feature >= 0), got {:?}",
                    &c[..3]
                )),
            }
        })
        .collect::<Result<Vec<_>, _>>()?;
    for (i, n) in nodes.iter().enumerate() {
        if n.feature >= features {
            return Err(format!("node {i} uses feature {} of {features}", n.feature));
        }
        for child in [n.left, n.right] {
            let valid = if child > 0 {
                (child as usize) < nodes.len() && child as usize > i
            } else {
                (child.unsigned_abs() as usize) < leaves.len()
            };
            if !valid {
                return Err(format!(
                    "node {i} points to {child} ({} nodes, {} leaves)",
                    nodes.len(),
                    leaves.len()
                ));
            }
        }
    }
    Ok(WeakClassifier { nodes, leaves })
}

//! The Haar cascade reader and detector on hand-made cascades: parsing, clear errors on bad or
//! truncated files, the detector finding the pattern a cascade encodes, and OpenCV's grouping.

use face_tracker::GrayImage;
use face_tracker::detect::{Cascade, DetectConfig, Detection, group};

/// A one-stage cascade on a 6×6 window with one two-rectangle feature, top half minus bottom
/// half (weights 1 and −1 over 6×3 each): a bright-over-dark edge passes.
fn edge_cascade(stage_threshold: &str, extra: &str) -> String {
    format!(
        r#"<?xml version="1.0"?>
<opencv_storage>
<cascade type_id="opencv-cascade-classifier"><stageType>BOOST</stageType>
  <featureType>HAAR</featureType>
  <height>6</height>
  <width>6</width>
  <stageParams><maxWeakCount>1</maxWeakCount></stageParams>
  <featureParams><maxCatCount>0</maxCatCount></featureParams>
  <stageNum>1</stageNum>
  <stages>
    <_>
      <maxWeakCount>1</maxWeakCount>
      <stageThreshold>{stage_threshold}</stageThreshold>
      <weakClassifiers>
        <_>
          <internalNodes>0 -1 0 0.2</internalNodes>
          <leafValues>-1. 1.</leafValues></_></weakClassifiers></_></stages>
  <features>
    <_>
      <rects>
        <_>0 0 6 3 1.</_>
        <_>0 3 6 3 -1.</_></rects>{extra}</_></features></cascade>
</opencv_storage>
"#
    )
}

#[test]
fn a_hand_made_cascade_parses_to_its_numbers() {
    let cascade = Cascade::parse(&edge_cascade("0.5", "")).unwrap();
    assert_eq!((cascade.width, cascade.height), (6, 6));
    assert_eq!(cascade.stages.len(), 1);
    assert_eq!(cascade.stages[0].threshold, 0.5);
    let weak = &cascade.stages[0].classifiers[0];
    assert_eq!(weak.nodes[0].left, 0);
    assert_eq!(weak.nodes[0].right, -1);
    assert_eq!(weak.nodes[0].threshold, 0.2);
    assert_eq!(weak.leaves, [-1.0, 1.0]);
    assert_eq!(cascade.features[0].len(), 2);
    assert_eq!(cascade.features[0][1].y, 3);
    assert_eq!(cascade.features[0][1].weight, -1.0);
}

#[test]
fn bad_and_truncated_cascades_are_clear_errors() {
    let good = edge_cascade("0.5", "");
    let cases: Vec<(String, &str)> = vec![
        (good[..good.len() / 2].to_string(), "not a valid XML"),
        ("<opencv_storage></opencv_storage>".into(), "no <cascade>"),
        (good.replace("HAAR", "LBP"), "only boosted Haar"),
        (good.replace("<stageNum>1", "<stageNum>3"), "truncated"),
        (good.replace("0 -1 0 0.2", "0 -1 7 0.2"), "feature 7 of 1"),
        (good.replace("0 -1 0 0.2", "0 -5 0 0.2"), "points to -5"),
        (good.replace("0 -1 0 0.2", "0 -1 0"), "four per node"),
        (good.replace("0 -1 0 0.2", "0 -1 -1 0.2"), "whole numbers"),
        (good.replace("0 -1 0 0.2", "0 -1.5 0 0.2"), "whole numbers"),
        (
            good.replace("0 3 6 3 -1.", "0 4 6 3 -1."),
            "outside the 6x6 window",
        ),
        (
            good.replace("0.5</stageThreshold>", "x</stageThreshold>"),
            "not a finite number",
        ),
        (edge_cascade("0.5", "<tilted>1</tilted>"), "tilted"),
    ];
    for (text, expected) in cases {
        let error = Cascade::parse(&text).unwrap_err();
        assert!(error.contains(expected), "{expected:?} not in {error:?}");
    }
    let missing = std::env::temp_dir().join("streampf-no-such-cascade.xml");
    let error = Cascade::load(&missing).unwrap_err().to_string();
    assert!(error.contains("streampf-no-such-cascade.xml"), "{error}");
}

/// A frame with bright-over-dark squares where the edge cascade should fire.
fn frame_with_edges(squares: &[(u32, u32, u32)]) -> GrayImage {
    let (w, h) = (160u32, 120u32);
    let mut levels = vec![128.0f32; (w * h) as usize];
    // Mild texture so no window is flat.
    for (i, v) in levels.iter_mut().enumerate() {
        *v += ((i * 7919) % 13) as f32 - 6.0;
    }
    for &(x0, y0, size) in squares {
        for y in y0..y0 + size {
            for x in x0..x0 + size {
                levels[(y * w + x) as usize] = if y < y0 + size / 2 { 230.0 } else { 20.0 };
            }
        }
    }
    GrayImage::from_levels(w, h, &levels).unwrap()
}

#[test]
fn the_detector_finds_the_pattern_its_cascade_encodes_at_its_scale() {
    let cascade = Cascade::parse(&edge_cascade("0.5", "")).unwrap();
    let frame = frame_with_edges(&[(20, 30, 36), (100, 40, 36)]);
    let config = DetectConfig {
        min_size: 30,
        max_size: Some(40),
        ..DetectConfig::default()
    };
    let mut found = cascade.detect(&frame, &config).unwrap();
    found.sort_by_key(|d| d.x);
    assert_eq!(found.len(), 2, "{found:?}");
    for (d, (x, y)) in found.iter().zip([(20, 30), (100, 40)]) {
        let want = Detection {
            x,
            y,
            width: 36,
            height: 36,
            neighbors: 0,
        };
        assert!(d.iou(&want) >= 0.5, "{d:?} against {want:?}");
    }
    // A stage threshold above the leaf value rejects everything.
    let never = Cascade::parse(&edge_cascade("1.5", "")).unwrap();
    assert!(never.detect(&frame, &config).unwrap().is_empty());
    // A flat frame has no windows with contrast.
    let flat = GrayImage::filled(160, 120, 90).unwrap();
    assert!(
        cascade
            .detect(&flat, &DetectConfig::default())
            .unwrap()
            .is_empty()
    );
    let bad = DetectConfig {
        scale_factor: 1.0,
        ..DetectConfig::default()
    };
    assert!(cascade.detect(&frame, &bad).is_err());
}

fn hit(x: i32, y: i32, size: i32) -> Detection {
    Detection {
        x,
        y,
        width: size,
        height: size,
        neighbors: 1,
    }
}

#[test]
fn grouping_keeps_clusters_with_enough_neighbours_and_drops_inner_ones() {
    // Four near-identical hits (kept, averaged; 50.5 rounds to even as OpenCV's cvRound), three elsewhere (dropped with min 3), and a
    // small cluster of five inside a stronger big one (dropped).
    let mut hits = vec![
        hit(10, 10, 50),
        hit(11, 10, 50),
        hit(10, 12, 52),
        hit(12, 11, 50),
    ];
    hits.extend([hit(200, 10, 40), hit(201, 10, 40), hit(200, 11, 40)]);
    hits.extend((0..8).map(|k| hit(300 + k % 2, 100, 100)));
    hits.extend((0..5).map(|_| hit(330, 130, 30)));
    let groups = group(&hits, 3);
    assert_eq!(groups.len(), 2, "{groups:?}");
    let first = groups.iter().find(|g| g.x < 100).unwrap();
    assert_eq!(
        (first.x, first.y, first.width, first.height, first.neighbors),
        (11, 11, 50, 50, 4)
    );
    assert!(groups.iter().any(|g| g.width == 100 && g.neighbors == 8));
    assert!(group(&[], 3).is_empty());
    // With no neighbours required every hit stands alone or with its cluster.
    assert_eq!(group(&hits[4..7], 0).len(), 1);
}

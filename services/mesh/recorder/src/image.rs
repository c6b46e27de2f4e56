//! The camera's frames as a viewer shows them: the image as `foxglove.RawImage` (8-bit grey,
//! `mono8`, lossless), and perception's estimate drawn over it as `foxglove.ImageAnnotations` (the
//! detected cable's centre line across the image, and its numbers as text). Both carry the frame's
//! stamp time, which is how a viewer pairs an overlay with its image.

use foxglove::messages::{
    Color, CompressedVideo, ImageAnnotations, Point2, PointsAnnotation, RawImage, TextAnnotation,
    Timestamp, points_annotation,
};
use messages::{CableObservationMsg, CameraFrameHeader, VideoUnit};

/// The frame a recorded image belongs to, in the camera's optical frame.
pub const FRAME_ID: &str = "camera";

/// A stamp time as the viewers' timestamp.
pub fn timestamp(time_ns: u64) -> Timestamp {
    Timestamp::new(
        (time_ns / 1_000_000_000) as u32,
        (time_ns % 1_000_000_000) as u32,
    )
}

/// A frame's image as `mono8`; `None` when the frame carries no image (ideal perception's frames
/// pass only the truth on) or its length is not the header's size.
pub fn raw_image(header: &CameraFrameHeader, image: &[u8]) -> Option<RawImage> {
    let (w, h) = (header.width as usize, header.height as usize);
    if image.is_empty() || w * h != image.len() {
        return None;
    }
    Some(RawImage {
        timestamp: Some(timestamp(header.stamp.time_ns)),
        frame_id: FRAME_ID.into(),
        width: header.width,
        height: header.height,
        encoding: "mono8".into(),
        step: header.width,
        data: image.to_vec().into(),
    })
}

/// An image read back from a record.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub time_ns: u64,
    pub width: u32,
    pub height: u32,
    /// 8-bit grey, row by row.
    pub data: Vec<u8>,
}

/// Why a recorded image cannot be used.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ImageError {
    #[error("encoding `{0}`: only mono8 is recorded")]
    Encoding(String),
    #[error("{width}x{height} with a row step of {step} needs {needed} bytes, it has {got}")]
    Size {
        width: u32,
        height: u32,
        step: u32,
        needed: usize,
        got: usize,
    },
}

impl TryFrom<RawImage> for Image {
    type Error = ImageError;
    fn try_from(raw: RawImage) -> Result<Image, ImageError> {
        if raw.encoding != "mono8" {
            return Err(ImageError::Encoding(raw.encoding));
        }
        let (w, h, step) = (raw.width as usize, raw.height as usize, raw.step as usize);
        let needed = if h == 0 { 0 } else { step * (h - 1) + w };
        if step < w || raw.data.len() < needed {
            return Err(ImageError::Size {
                width: raw.width,
                height: raw.height,
                step: raw.step,
                needed,
                got: raw.data.len(),
            });
        }
        let data = if step == w {
            raw.data[..w * h].to_vec()
        } else {
            (0..h)
                .flat_map(|r| raw.data[r * step..r * step + w].iter().copied())
                .collect()
        };
        Ok(Image {
            time_ns: raw.timestamp.as_ref().map_or(0, Timestamp::total_nanos),
            width: raw.width,
            height: raw.height,
            data,
        })
    }
}

/// An access unit of the camera's H.264 stream as `foxglove.CompressedVideo`: Annex B, one
/// access unit a message (a keyframe with its SPS and PPS: the camera's source adds the last
/// ones sent where a keyframe lacks them), at its frame's time.
pub fn compressed_video(unit: &VideoUnit, bytes: &[u8]) -> CompressedVideo {
    CompressedVideo {
        timestamp: Some(timestamp(unit.time_ns)),
        frame_id: FRAME_ID.into(),
        data: bytes.to_vec().into(),
        format: "h264".into(),
    }
}

/// A video unit read back from a record.
#[derive(Clone, Debug, PartialEq)]
pub struct Video {
    pub time_ns: u64,
    /// `h264`.
    pub format: String,
    /// The access unit, Annex B.
    pub data: Vec<u8>,
}

impl From<CompressedVideo> for Video {
    fn from(v: CompressedVideo) -> Video {
        Video {
            time_ns: v.timestamp.as_ref().map_or(0, Timestamp::total_nanos),
            format: v.format,
            data: v.data.to_vec(),
        }
    }
}

const FOUND: Color = Color {
    r: 0.1,
    g: 0.95,
    b: 0.2,
    a: 1.0,
};
const NOT_FOUND: Color = Color {
    r: 1.0,
    g: 0.25,
    b: 0.15,
    a: 1.0,
};
const TEXT_BACKGROUND: Color = Color {
    r: 0.0,
    g: 0.0,
    b: 0.0,
    a: 0.6,
};

/// Perception's estimate over a `width x height` frame: where the line it found crosses the image
/// border (the conventions of `model::camera`: centred pixel coordinates, here moved to the viewers'
/// origin at the image's top-left corner), and x_g and Theta as text; only the text when the cable
/// was not found.
pub fn estimate_overlay(o: &CableObservationMsg, width: u32, height: u32) -> ImageAnnotations {
    let t = timestamp(o.stamp.time_ns);
    let est = o.observation;
    let (w, h) = (width as f64, height as f64);
    let line = (est.found != 0)
        .then(|| model::CableLine::from_polar(est.rho, est.theta, w, h))
        .flatten();
    let points = line
        .map(|l| {
            vec![PointsAnnotation {
                timestamp: Some(t),
                r#type: points_annotation::Type::LineList as i32,
                points: l
                    .ends
                    .iter()
                    .map(|p| Point2 {
                        x: p[0] + 0.5 * w,
                        y: p[1] + 0.5 * h,
                    })
                    .collect(),
                outline_color: Some(FOUND),
                thickness: 2.0,
                ..Default::default()
            }]
        })
        .unwrap_or_default();
    let text = if line.is_some() {
        format!(
            "x_g {:+.3}  Theta {:+.1} deg",
            est.x_g,
            est.theta.to_degrees()
        )
    } else {
        "cable not found".to_owned()
    };
    ImageAnnotations {
        timestamp: Some(t),
        points,
        texts: vec![TextAnnotation {
            timestamp: Some(t),
            position: Some(Point2 { x: 4.0, y: 14.0 }),
            text,
            font_size: 12.0,
            text_color: Some(if line.is_some() { FOUND } else { NOT_FOUND }),
            background_color: Some(TEXT_BACKGROUND),
            ..Default::default()
        }],
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::{CableObservationData, Stamp, StepStatus};

    #[test]
    fn an_image_goes_into_a_raw_image_and_back() {
        let header = CameraFrameHeader {
            stamp: Stamp::new(5, 3_200_000_001, 0, 16, StepStatus::Running),
            width: 4,
            height: 3,
            ..Default::default()
        };
        let pixels: Vec<u8> = (0..12).collect();
        let raw = raw_image(&header, &pixels).unwrap();
        assert_eq!((raw.encoding.as_str(), raw.step), ("mono8", 4));
        let back = Image::try_from(raw.clone()).unwrap();
        assert_eq!(back.time_ns, 3_200_000_001);
        assert_eq!((back.width, back.height, back.data), (4, 3, pixels.clone()));
        assert!(raw_image(&header, &[]).is_none(), "no image, no RawImage");
        assert!(raw_image(&header, &pixels[..11]).is_none());
        // Padded rows are cut; a short buffer or another encoding is refused.
        let padded = RawImage {
            step: 5,
            data: (0..15).collect::<Vec<u8>>().into(),
            ..raw.clone()
        };
        assert_eq!(
            Image::try_from(padded).unwrap().data,
            vec![0, 1, 2, 3, 5, 6, 7, 8, 10, 11, 12, 13]
        );
        let short = RawImage {
            data: vec![0u8; 11].into(),
            ..raw.clone()
        };
        assert!(matches!(
            Image::try_from(short),
            Err(ImageError::Size { .. })
        ));
        let rgb = RawImage {
            encoding: "rgb8".into(),
            ..raw
        };
        assert!(matches!(Image::try_from(rgb), Err(ImageError::Encoding(_))));
    }

    #[test]
    fn a_video_unit_goes_into_compressed_video_and_back() {
        let unit = VideoUnit {
            number: 3,
            time_ns: 2_400_000_007,
            flags: VideoUnit::KEYFRAME,
            ..Default::default()
        };
        let au = [
            0u8, 0, 0, 1, 0x67, 1, 0, 0, 0, 1, 0x68, 2, 0, 0, 0, 1, 0x65, 3,
        ];
        let v = compressed_video(&unit, &au);
        assert_eq!((v.format.as_str(), v.frame_id.as_str()), ("h264", FRAME_ID));
        let back = Video::from(v);
        assert_eq!(
            back,
            Video {
                time_ns: 2_400_000_007,
                format: "h264".into(),
                data: au.to_vec()
            }
        );
    }

    #[test]
    fn the_overlay_is_the_line_perception_found() {
        let (w, h) = (320u32, 240u32);
        // A vertical cable 0.1 of the width right of the centre: rho = 32 px at Theta = 0.
        let o = CableObservationMsg {
            stamp: Stamp::new(9, 1_800_000_000, 0, 9, StepStatus::Running),
            observation: CableObservationData {
                found: 1,
                rho: 32.0,
                theta: 0.0,
                x_g: 0.1,
                ..Default::default()
            },
        };
        let a = estimate_overlay(&o, w, h);
        assert_eq!(a.timestamp, Some(timestamp(1_800_000_000)));
        let line = &a.points[0];
        assert_eq!(line.r#type, points_annotation::Type::LineList as i32);
        let xs: Vec<f64> = line.points.iter().map(|p| p.x).collect();
        let ys: Vec<f64> = line.points.iter().map(|p| p.y).collect();
        // From the top border to the bottom one, at column 160 + 32.
        assert!(xs.iter().all(|x| (x - 192.0).abs() < 1e-9), "{xs:?}");
        assert!(ys.contains(&0.0) && ys.contains(&240.0), "{ys:?}");
        assert!(
            a.texts[0].text.contains("x_g +0.100"),
            "{}",
            a.texts[0].text
        );
        let lost = CableObservationMsg {
            observation: CableObservationData::default(),
            ..o
        };
        let a = estimate_overlay(&lost, w, h);
        assert!(a.points.is_empty());
        assert_eq!(a.texts[0].text, "cable not found");
    }
}

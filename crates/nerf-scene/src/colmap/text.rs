//! COLMAP's text model files (`cameras.txt`, `images.txt`, `points3D.txt`), read and written
//! for the parent module. Lines starting with `#` and empty lines are comments,
//! except that an image always takes two lines, the second (its 2D features) empty when it
//! has none:
//!
//! * `cameras.txt`: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...` (the model by name);
//! * `images.txt`: `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME` (world-to-camera; the name is
//!   the rest of the line), then `X Y POINT3D_ID` triples (`-1`: no 3D point);
//! * `points3D.txt`: `POINT3D_ID X Y Z R G B ERROR` then the track as `IMAGE_ID POINT2D_IDX`
//!   pairs (not kept).
//!
//! Files are read as streams, each line bounded by [`MAX_TEXT_LINE_BYTES`]; numbers are
//! written in the shortest form that reads back to the same value (Rust's `{:?}`, which
//! COLMAP's readers parse).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::str::FromStr;

use anyhow::{anyhow, Result};

use super::{
    camera_problem, image_problem, point_step, write_records, ColmapCameraRecord, ColmapImage,
    ColmapPoint2D, ColmapPoint3D, MAX_CAMERAS, MAX_CAMERAS_FILE_BYTES, MAX_IMAGES,
    MAX_IMAGES_FILE_BYTES, MAX_POINTS3D_FILE_BYTES, MAX_TEXT_LINE_BYTES,
};
use nerf_files::bounded_read::check_regular_file;

/// Writes `cameras.txt` (cameras already checked).
pub(super) fn write_cameras(
    path: &Path,
    cameras: &BTreeMap<u32, ColmapCameraRecord>,
) -> Result<()> {
    let header = [
        "Camera list with one line of data per camera:",
        "  CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
    ];
    write_text(path, &header, "cameras", cameras.values(), |w, c| {
        write!(w, "{} {} {} {}", c.id, c.model, c.width, c.height)?;
        for p in &c.params {
            write!(w, " {p:?}")?;
        }
        Ok(writeln!(w)?)
    })
}

/// Writes `images.txt` (images already checked): two lines per image, the second empty when
/// it has no 2D features.
pub(super) fn write_images(path: &Path, images: &[ColmapImage]) -> Result<()> {
    let header = [
        "Image list with two lines of data per image:",
        "  IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "  POINTS2D[] as (X, Y, POINT3D_ID)",
    ];
    write_text(path, &header, "images", images, |w, image| {
        write!(w, "{}", image.id)?;
        for v in image.qvec.iter().chain(&image.tvec) {
            write!(w, " {v:?}")?;
        }
        writeln!(w, " {} {}", image.camera_id, image.name)?;
        for (i, p) in image.points2d.iter().enumerate() {
            let sep = if i == 0 { "" } else { " " };
            match p.point3d_id {
                Some(id) => write!(w, "{sep}{:?} {:?} {id}", p.xy[0], p.xy[1])?,
                None => write!(w, "{sep}{:?} {:?} -1", p.xy[0], p.xy[1])?,
            }
        }
        Ok(writeln!(w)?)
    })
}

/// Writes `points3D.txt` with empty tracks (points already checked).
pub(super) fn write_points3d(path: &Path, points: &[ColmapPoint3D]) -> Result<()> {
    let header = [
        "3D point list with one line of data per point:",
        "  POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
    ];
    write_text(path, &header, "points", points, |w, p| {
        let [x, y, z] = p.xyz;
        let [r, g, b] = p.rgb;
        Ok(writeln!(
            w,
            "{} {x:?} {y:?} {z:?} {r} {g} {b} {:?}",
            p.id, p.error
        )?)
    })
}

/// Writes a model file at `path` as COLMAP does: the `header` lines and a `# Number of
/// {what}: N` line as comments, then each record by `write_record`.
fn write_text<'a, T: 'a>(
    path: &Path,
    header: &[&str],
    what: &str,
    records: impl IntoIterator<Item = &'a T, IntoIter: ExactSizeIterator>,
    write_record: impl Fn(&mut BufWriter<File>, &T) -> Result<()>,
) -> Result<()> {
    let head = |w: &mut BufWriter<File>, n: usize| -> Result<()> {
        for line in header {
            writeln!(w, "# {line}")?;
        }
        Ok(writeln!(w, "# Number of {what}: {n}")?)
    };
    write_records(path, records, head, write_record)
}

/// A text file read line by line, each line bounded by [`MAX_TEXT_LINE_BYTES`]; errors name
/// the file and the line.
struct TextLines {
    reader: BufReader<File>,
    what: &'static str,
    path: PathBuf,
    line_no: usize,
    line: String,
}

impl TextLines {
    /// Opens the regular file `path` of at most `max_bytes`.
    fn open(path: &Path, what: &'static str, max_bytes: u64) -> Result<(Self, u64)> {
        let len = check_regular_file(path, what, max_bytes)?;
        let file =
            File::open(path).map_err(|e| anyhow!("cannot read {what} {}: {e}", path.display()))?;
        let lines = TextLines {
            reader: BufReader::new(file),
            what,
            path: path.to_path_buf(),
            line_no: 0,
            line: String::new(),
        };
        Ok((lines, len))
    }

    /// An error at the current line.
    fn error(&self, message: impl std::fmt::Display) -> anyhow::Error {
        anyhow!(
            "{} {} line {}: {message}",
            self.what,
            self.path.display(),
            self.line_no
        )
    }

    /// Moves to the next line; false at the end of the file.
    fn advance(&mut self) -> Result<bool> {
        self.line.clear();
        let limit = MAX_TEXT_LINE_BYTES as u64 + 1;
        let n = (&mut self.reader)
            .take(limit)
            .read_line(&mut self.line)
            .map_err(|e| {
                anyhow!(
                    "cannot read {} {} after line {}: {e}",
                    self.what,
                    self.path.display(),
                    self.line_no
                )
            })?;
        if n == 0 {
            return Ok(false);
        }
        self.line_no += 1;
        if self.line.len() > MAX_TEXT_LINE_BYTES {
            return Err(self.error(format!(
                "a line longer than the {MAX_TEXT_LINE_BYTES} bytes read"
            )));
        }
        Ok(true)
    }

    /// Moves to the next line that is neither empty nor a comment; false at the end.
    fn advance_to_data(&mut self) -> Result<bool> {
        while self.advance()? {
            let line = self.line();
            if !line.is_empty() && !line.starts_with('#') {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// The current line, trimmed.
    fn line(&self) -> &str {
        self.line.trim()
    }

    /// `field` parsed as a `T`; `what` names it for the error.
    fn parse<T: FromStr>(&self, field: &str, what: &str) -> Result<T> {
        field
            .parse()
            .map_err(|_| self.error(format!("{what} {field:?} is not a valid number here")))
    }

    /// `field` parsed as a finite number.
    fn parse_finite(&self, field: &str, what: &str) -> Result<f64> {
        let v: f64 = self.parse(field, what)?;
        if !v.is_finite() {
            return Err(self.error(format!("{what} is {field}, not a finite number")));
        }
        Ok(v)
    }
}

/// The first `n` whitespace-separated fields of `line` (fewer when it has fewer) and the rest
/// of the line, trimmed.
fn split_fields(line: &str, n: usize) -> (Vec<&str>, &str) {
    let mut rest = line;
    let mut fields = Vec::with_capacity(n);
    while fields.len() < n {
        rest = rest.trim_start();
        if rest.is_empty() {
            break;
        }
        let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
        fields.push(&rest[..end]);
        rest = &rest[end..];
    }
    (fields, rest.trim())
}

/// Reads `cameras.txt`: one camera per line, `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...`.
pub(super) fn read_cameras(path: &Path) -> Result<BTreeMap<u32, ColmapCameraRecord>> {
    let (mut lines, _) = TextLines::open(path, "COLMAP cameras file", MAX_CAMERAS_FILE_BYTES)?;
    let mut cameras = BTreeMap::new();
    while lines.advance_to_data()? {
        let fields: Vec<&str> = lines.line().split_whitespace().collect();
        if fields.len() < 4 {
            return Err(lines.error(format!(
                "{} fields, not CAMERA_ID MODEL WIDTH HEIGHT PARAMS...",
                fields.len()
            )));
        }
        let id: u32 = lines.parse(fields[0], "camera id")?;
        let params = fields[4..]
            .iter()
            .map(|f| lines.parse_finite(f, "camera parameter"))
            .collect::<Result<Vec<f64>>>()?;
        let camera = ColmapCameraRecord {
            id,
            model: fields[1].to_string(),
            width: lines.parse(fields[2], "width")?,
            height: lines.parse(fields[3], "height")?,
            params,
        };
        if let Some(p) = camera_problem(&camera) {
            return Err(lines.error(p));
        }
        if cameras.len() >= MAX_CAMERAS {
            return Err(lines.error(format!("more than {MAX_CAMERAS} cameras")));
        }
        if cameras.insert(id, camera).is_some() {
            return Err(lines.error(format!("a second camera with id {id}")));
        }
    }
    Ok(cameras)
}

/// Reads `images.txt`: two lines per image, `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`
/// (the name is the rest of the line) and its 2D features as `X Y POINT3D_ID` triples (an
/// empty line when it has none; read whatever it holds, as COLMAP does). The features are
/// kept when `keep_points2d`; their line is checked either way, so an image whose feature
/// line is missing is an error rather than an image lost.
pub(super) fn read_images(path: &Path, keep_points2d: bool) -> Result<Vec<ColmapImage>> {
    let (mut lines, _) = TextLines::open(path, "COLMAP images file", MAX_IMAGES_FILE_BYTES)?;
    let mut images = Vec::new();
    while lines.advance_to_data()? {
        let (fields, name) = split_fields(lines.line(), 9);
        if fields.len() < 9 || name.is_empty() {
            return Err(lines.error(
                "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME (the first of an image's two lines)",
            ));
        }
        let mut pose = [0.0; 7];
        for (v, (f, what)) in pose.iter_mut().zip(
            fields[1..8]
                .iter()
                .zip(["qw", "qx", "qy", "qz", "tx", "ty", "tz"]),
        ) {
            *v = lines.parse_finite(f, what)?;
        }
        let mut image = ColmapImage {
            id: lines.parse(fields[0], "image id")?,
            qvec: [pose[0], pose[1], pose[2], pose[3]],
            tvec: [pose[4], pose[5], pose[6]],
            camera_id: lines.parse(fields[8], "camera id")?,
            name: name.to_string(),
            points2d: Vec::new(),
        };
        if let Some(p) = image_problem(&image) {
            return Err(lines.error(p));
        }
        if images.len() >= MAX_IMAGES {
            return Err(lines.error(format!("more than {MAX_IMAGES} images")));
        }
        if lines.advance()? {
            image.points2d = read_points2d_line(&lines, &image.name, keep_points2d)?;
        }
        images.push(image);
    }
    Ok(images)
}

/// The 2D features on the current line of `lines` (the second line of image `name`), kept
/// only when `keep`.
fn read_points2d_line(lines: &TextLines, name: &str, keep: bool) -> Result<Vec<ColmapPoint2D>> {
    let fields: Vec<&str> = lines.line().split_whitespace().collect();
    if !fields.len().is_multiple_of(3) {
        return Err(lines.error(format!(
            "{} fields on the 2D feature line of image {name:?}, not X Y POINT3D_ID triples (each image takes two lines, the second empty when it has no features)",
            fields.len()
        )));
    }
    if !keep {
        return Ok(Vec::new());
    }
    fields
        .chunks_exact(3)
        .map(|t| {
            let point3d_id = match t[2] {
                "-1" => None,
                id => Some(lines.parse(id, "3D point id")?),
            };
            Ok(ColmapPoint2D {
                xy: [
                    lines.parse_finite(t[0], "feature x")?,
                    lines.parse_finite(t[1], "feature y")?,
                ],
                point3d_id,
            })
        })
        .collect()
}

/// The fewest bytes a data line of `points3D.txt` takes (`0 0 0 0 0 0 0 0` and its newline).
const MIN_POINT3D_LINE_BYTES: u64 = 16;

/// Reads `points3D.txt`: one point per line, `POINT3D_ID X Y Z R G B ERROR TRACK...` (the
/// track is not kept), keeping at most `max_points` spread evenly over the file (it is read
/// twice when it may hold more: once to count).
pub(super) fn read_points3d(path: &Path, max_points: usize) -> Result<Vec<ColmapPoint3D>> {
    const WHAT: &str = "COLMAP points file";
    let (mut lines, len) = TextLines::open(path, WHAT, MAX_POINTS3D_FILE_BYTES)?;
    let step = if len / MIN_POINT3D_LINE_BYTES <= max_points as u64 {
        1
    } else {
        let (mut counter, _) = TextLines::open(path, WHAT, MAX_POINTS3D_FILE_BYTES)?;
        let mut total = 0u64;
        while counter.advance_to_data()? {
            total += 1;
        }
        point_step(total, max_points)
    };
    let mut points = Vec::new();
    let mut index = 0u64;
    while lines.advance_to_data()? && points.len() < max_points {
        let keep = index.is_multiple_of(step);
        index += 1;
        if !keep {
            continue;
        }
        let (fields, _track) = split_fields(lines.line(), 8);
        if fields.len() < 8 {
            return Err(lines.error(
                "expected POINT3D_ID X Y Z R G B ERROR and the track (IMAGE_ID POINT2D_IDX pairs)",
            ));
        }
        let mut xyz = [0.0; 3];
        for (v, (f, what)) in xyz.iter_mut().zip(fields[1..4].iter().zip(["x", "y", "z"])) {
            *v = lines.parse_finite(f, what)?;
        }
        points.push(ColmapPoint3D {
            id: lines.parse(fields[0], "3D point id")?,
            xyz,
            rgb: [
                lines.parse(fields[4], "red (0 to 255)")?,
                lines.parse(fields[5], "green (0 to 255)")?,
                lines.parse(fields[6], "blue (0 to 255)")?,
            ],
            error: lines.parse_finite(fields[7], "error")?,
        });
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_and_the_rest_of_a_line() {
        let (f, rest) = split_fields("1  2\t3 a b.png ", 3);
        assert_eq!((f, rest), (vec!["1", "2", "3"], "a b.png"));
        let (f, rest) = split_fields("1 2", 3);
        assert_eq!((f, rest), (vec!["1", "2"], ""));
    }
}

//! Pairing: the datasets of each side by object and sensor, their rows by commanded pose, and
//! the images at the measuring size.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use image::RgbImage;

use super::error::EvalError;
use crate::calibration::model::Calibration;
use crate::dataset::{DatasetError, Manifest, PoseRow, Source, read_rows};
use crate::geometry::stl::Mesh;
use crate::pose::Pose;

/// Two poses are the same pose when x, y, z (mm) and yaw (deg) each differ by at most this.
pub const POSE_TOLERANCE: f64 = 1e-6;

/// Whether two poses are the same within [`POSE_TOLERANCE`].
pub fn same_pose(a: &Pose, b: &Pose) -> bool {
    (a.x_mm - b.x_mm).abs() <= POSE_TOLERANCE
        && (a.y_mm - b.y_mm).abs() <= POSE_TOLERANCE
        && (a.z_mm - b.z_mm).abs() <= POSE_TOLERANCE
        && (a.yaw_deg - b.yaw_deg).abs() <= POSE_TOLERANCE
}

/// One dataset read from disk.
#[derive(Clone)]
pub(super) struct DatasetInfo {
    pub dir: PathBuf,
    pub manifest: Manifest,
    pub rows: Vec<PoseRow>,
}

impl DatasetInfo {
    pub fn load(dir: &Path) -> Result<Self, EvalError> {
        let wrap = |source| EvalError::Dataset { dir: dir.to_path_buf(), source };
        let manifest = Manifest::load(dir).map_err(wrap)?;
        let rows = read_rows(dir).map_err(wrap)?;
        Ok(Self { dir: dir.to_path_buf(), manifest, rows })
    }

    pub fn key(&self) -> (String, String) {
        (self.manifest.object.name.clone(), self.manifest.sensor.to_string())
    }

    pub fn rows_of(&self, source: Source) -> impl Iterator<Item = &PoseRow> {
        self.rows.iter().filter(move |r| r.source == source)
    }

    /// The captured rows: `real` and `simulated` (a simulated rig's frames stand on the
    /// measured side like a real rig's).
    pub fn captured_rows(&self) -> impl Iterator<Item = &PoseRow> {
        self.rows.iter().filter(|r| r.source.is_captured())
    }
}

/// Datasets under `root` keyed by (object, sensor); a key twice is an error.
fn load_side(root: &Path, side: &'static str) -> Result<BTreeMap<(String, String), DatasetInfo>, EvalError> {
    let dirs = crate::dataset::find_datasets(root).map_err(|source| EvalError::Dataset { dir: root.to_path_buf(), source })?;
    if dirs.is_empty() {
        return Err(EvalError::NoDatasets { side, dir: root.to_path_buf() });
    }
    let mut out = BTreeMap::new();
    for d in dirs {
        let info = DatasetInfo::load(&d)?;
        let key = info.key();
        if let Some(first) = out.get(&key) {
            let first: &DatasetInfo = first;
            return Err(EvalError::DuplicateDataset { side, object: key.0, sensor: key.1, first: first.dir.clone(), second: d });
        }
        out.insert(key, info);
    }
    Ok(out)
}

/// The three sides of an evaluation, read from disk: real and synthetic datasets keyed by
/// (object, sensor), and the collected (training) datasets the baselines draw on.
pub(super) struct Sides {
    pub real: BTreeMap<(String, String), DatasetInfo>,
    pub synthetic: BTreeMap<(String, String), DatasetInfo>,
    pub collected: Vec<DatasetInfo>,
}

impl Sides {
    /// Reads the datasets under each root. `collected` empty: the synthetic datasets (their
    /// real rows) are the collected set. `objects` non-empty keeps only those objects on the
    /// real and synthetic sides (after the collected set is taken: baselines may use any
    /// object of the sensor); an object with no real dataset is an error.
    pub fn load(real_root: &Path, synthetic_root: &Path, collected: &[PathBuf], objects: &[String]) -> Result<Self, EvalError> {
        let mut real = load_side(real_root, "real")?;
        let mut synthetic = load_side(synthetic_root, "synthetic")?;
        let collected_sets: Vec<DatasetInfo> = if collected.is_empty() {
            synthetic.values().cloned().collect()
        } else {
            let mut v = Vec::new();
            for root in collected {
                let dirs = crate::dataset::find_datasets(root).map_err(|source| EvalError::Dataset { dir: root.clone(), source })?;
                if dirs.is_empty() {
                    return Err(EvalError::NoDatasets { side: "collected", dir: root.clone() });
                }
                for d in dirs {
                    v.push(DatasetInfo::load(&d)?);
                }
            }
            v
        };
        if !objects.is_empty() {
            if let Some(object) = objects.iter().find(|o| !real.keys().any(|(name, _)| name == *o)) {
                return Err(EvalError::UnknownObject { object: object.clone(), dir: real_root.to_path_buf() });
            }
            real.retain(|(name, _), _| objects.contains(name));
            synthetic.retain(|(name, _), _| objects.contains(name));
        }
        Ok(Self { real, synthetic, collected: collected_sets })
    }
}

/// The rows of a real and a synthetic dataset of one object and sensor, paired by commanded
/// pose ([`same_pose`]): each real row takes the first synthetic row of its pose not taken
/// yet, in row order.
pub(super) struct RowPairs<'a> {
    /// (real, synthetic) twins, in real-row order.
    pub twins: Vec<(&'a PoseRow, &'a PoseRow)>,
    /// Real rows without a twin, in row order.
    pub unpaired_real: Vec<&'a PoseRow>,
    /// Synthetic rows left over, in row order.
    pub unpaired_synthetic: Vec<&'a PoseRow>,
}

/// Pairs the captured (`source=real` or `simulated`) rows of `real` with the `source=synthetic` rows of `synthetic`.
pub(super) fn pair_rows<'a>(real: &'a DatasetInfo, synthetic: &'a DatasetInfo) -> RowPairs<'a> {
    let synthetic_rows: Vec<&PoseRow> = synthetic.rows_of(Source::Synthetic).collect();
    let mut used = vec![false; synthetic_rows.len()];
    let (mut twins, mut unpaired_real) = (Vec::new(), Vec::new());
    for row in real.captured_rows() {
        let pose = row.commanded();
        match synthetic_rows.iter().enumerate().find(|(i, t)| !used[*i] && same_pose(&t.commanded(), &pose)) {
            Some((i, twin)) => {
                used[i] = true;
                twins.push((row, *twin));
            }
            None => unpaired_real.push(row),
        }
    }
    let unpaired_synthetic = synthetic_rows.iter().zip(&used).filter(|(_, u)| !**u).map(|(r, _)| *r).collect();
    RowPairs { twins, unpaired_real, unpaired_synthetic }
}
/// Reads the image `rel` of the dataset at `dir` by the dataset rules (below the dataset with
/// no symlink, a regular file, bounded, its pixel count bounded before decoding).
pub(super) fn load_image(dir: &Path, rel: &str) -> Result<RgbImage, EvalError> {
    use crate::dataset::durable;
    let dataset = |source| EvalError::Dataset { dir: dir.to_path_buf(), source };
    let bytes = durable::read_below(dir, Path::new(rel), durable::MAX_IMAGE_BYTES).map_err(dataset)?;
    let image = durable::decode_image(&bytes).map_err(|reason| dataset(DatasetError::BadImage { path: dir.join(rel), reason }))?;
    Ok(image.to_rgb8())
}

/// [`load_image`], resized to `size` x `size` (bilinear) when it is not already.
pub(super) fn load_at(dir: &Path, rel: &str, size: u32) -> Result<RgbImage, EvalError> {
    Ok(resize_square(load_image(dir, rel)?, size))
}

/// `img` at `size` x `size`.
pub(super) fn resized(img: RgbImage, size: u32) -> RgbImage {
    resize_square(img, size)
}

fn resize_square(img: RgbImage, size: u32) -> RgbImage {
    if img.dimensions() == (size, size) { img } else { image::imageops::resize(&img, size, size, image::imageops::FilterType::Triangle) }
}

/// The dataset's calibration at `size` x `size`: the file its manifest names (read only where
/// [`crate::dataset::named`] allows), else (none, `default`, or a file that cannot be used) the
/// default for its image size, which is what `rig collect` renders with then.
pub(super) fn calibration_at(info: &DatasetInfo, native: (u32, u32), size: u32) -> Option<Calibration> {
    let calib = match info.manifest.calibration.as_deref() {
        None | Some("default") | Some("none") => Calibration::default_for(native.0, native.1),
        Some(named) => {
            let bytes =
                crate::dataset::named::read_named(&info.dir, "calibration", named, None, crate::untrusted::MAX_CONFIG_BYTES).ok()??;
            Calibration::from_toml(std::str::from_utf8(&bytes).ok()?, named).ok()?
        }
    };
    Some(calib.scaled_to(size, size))
}

/// The object's mesh: the STL its manifest names when rig may read it, it is there and it
/// matches its sha256 ([`crate::dataset::ObjectInfo::stl_bytes`]), else the library object of
/// that name. A path the manifest names that rig refuses to open (a device, a FIFO, a symlink
/// below the dataset) is an error, never quietly replaced by the library object.
pub(super) fn mesh_of(dir: &Path, manifest: &Manifest) -> Result<Option<Mesh>, EvalError> {
    use crate::dataset::DatasetError as D;
    match manifest.object.stl_bytes(dir, &dir.join(crate::dataset::MANIFEST_FILE), crate::geometry::stl::MAX_STL_BYTES) {
        Ok(Some(bytes)) => {
            if let Ok(mesh) = Mesh::from_bytes(&bytes) {
                return Ok(Some(mesh));
            }
        }
        Ok(None) | Err(D::StlMissing { .. } | D::StlUnusable { .. } | D::StlChanged { .. }) => {}
        Err(refused) => return Err(EvalError::Dataset { dir: dir.to_path_buf(), source: refused }),
    }
    Ok(crate::geometry::objects::load_object(&manifest.object.name).ok())
}

pub(super) fn describe(object: &str, sensor: &str, side: &str, row: &PoseRow) -> String {
    format!("{side} {object}/{sensor} pose_id {} ({}, {}, {}, {})", row.pose_id, row.x_mm, row.y_mm, row.z_mm, row.yaw_deg)
}

//! The model package: a directory in diffusers' layout, its `model.toml`, and the checks that
//! each ONNX model takes and returns what the pipeline will feed and read.
//!
//! ```text
//! model.toml                        name, resolution, modalities, prompt template, latent scale, hint encoding
//! tokenizer/tokenizer.json          HF tokenizers format (CLIP BPE)
//! text_encoder/model.onnx           input_ids [B,77] (int32|int64) -> last_hidden_state [B,77,D]
//! controlnet/model.onnx             sample, timestep, encoder_hidden_states, controlnet_cond, conditioning_scale
//!                                   -> down_block_res_samples_0..N-1, mid_block_res_sample
//! unet/model.onnx                   sample, timestep, encoder_hidden_states,
//!                                   down_block_additional_residual_0..N-1, mid_block_additional_residual -> out_sample
//! vae_decoder/model.onnx            latent_sample (already divided by the latent scale) -> sample in [-1, 1]
//! scheduler/scheduler_config.json   diffusers scheduler config
//! */model.onnx.data                 optional: all of that model's weights, beside its model.onnx
//!                                   (ONNX Runtime reads it; needed over 2 GB; hashed like every file)
//! ```
//!
//! Element types and shapes are read from the sessions ([`TensorSpec`]), never assumed: ids may
//! be int32 or int64, the timestep float or integer, of rank 0 or 1. A model that does not fit
//! is rejected at load time with an error naming the file and the tensor.
//!
//! `model.toml` (all keys but `name` optional):
//!
//! ```toml
//! name = "multidiffsense-sd15"
//! resolution = [512, 512]            # width, height in pixels (default 512 x 512)
//! modalities = ["TacTip", "ViTac", "ViTacTip"]
//! prompt_template = "multidiffsense" # the only template so far: prompt::mds_prompt
//! latent_scale = 0.18215
//! hint_encoding = "rgb01"            # control RGB scaled to [0,1] ("rgb11": to [-1,1])
//! vae_scale_factor = 8               # image pixels per latent pixel
//! end_token = "<|endoftext|>"        # padding token of the tokenizer
//! sampling_steps = 20                # how the model is meant to be sampled: the defaults of
//! guidance = 1.0                     #   every `rig synth` mode, each flag overriding its key
//! sampler = "dpm++2m"                #   (else `rig synth one`: 50 steps, guidance 9; fills: 20
//! eta = 0.0                          #   steps, guidance 1; ddim; eta 0)
//! ```

use std::io::Read;
use std::path::{Path, PathBuf};

#[cfg(feature = "synth")]
use ort::value::{TensorElementType, ValueType};
use sha2::{Digest, Sha256};

use super::SynthError;
use super::scheduler::{NoiseSchedule, SchedulerConfig};

/// Files every package must hold, relative to its directory.
pub const PACKAGE_FILES: [&str; 7] = [
    "model.toml",
    "tokenizer/tokenizer.json",
    "text_encoder/model.onnx",
    "controlnet/model.onnx",
    "unet/model.onnx",
    "vae_decoder/model.onnx",
    "scheduler/scheduler_config.json",
];

pub use super::model_toml::{ControlColourMap, HintEncoding, ModelConfig, Sampling};

impl ModelConfig {
    /// Reads and validates `model.toml`.
    pub fn read(path: &Path) -> Result<Self, SynthError> {
        let text = crate::untrusted::read_text(path, crate::untrusted::MAX_CONFIG_BYTES)
            .map_err(|source| SynthError::Io { path: path.to_path_buf(), source })?;
        Self::parse(&text).map_err(|e| match e {
            super::model_toml::ModelTomlError::Syntax(source) => SynthError::ModelToml { path: path.to_path_buf(), source },
            super::model_toml::ModelTomlError::Bad { field, value, reason } => {
                SynthError::BadModelConfig { path: path.to_path_buf(), field, value, reason }
            }
        })
    }
}

/// A package directory whose files are all there and whose configs parse. The ONNX models are
/// checked when the sessions are made ([`ModelIo::expect`] and its siblings).
#[derive(Debug, Clone)]
pub struct ModelPackage {
    pub dir: PathBuf,
    pub config: ModelConfig,
    pub schedule: NoiseSchedule,
}

impl ModelPackage {
    /// Opens `dir`: all of [`PACKAGE_FILES`] must exist (the error lists every missing one), each
    /// a regular file reached without a symlink below `dir` ([`crate::confine`]): a package
    /// from a colleague cannot make rig read, hash or hand ONNX Runtime a file elsewhere.
    pub fn open(dir: &Path) -> Result<Self, SynthError> {
        use crate::confine::{ConfineError, EntryKind, RootDir};
        // A folder that is not there (or not a folder) lists every file as missing, as before.
        let root = match RootDir::open(dir) {
            Ok(root) => Some(root),
            Err(ConfineError::Missing { .. } | ConfineError::NotFolder { .. }) => None,
            Err(e) => return Err(e.into()),
        };
        let mut missing = Vec::new();
        for f in PACKAGE_FILES {
            let found = match &root {
                Some(root) => root.stat(f)?,
                None => None,
            };
            match found {
                None => missing.push(dir.join(f)),
                Some(info) if info.kind == EntryKind::File => {}
                Some(info) if info.kind == EntryKind::Symlink => {
                    return Err(ConfineError::Symlink { root: dir.to_path_buf(), path: dir.join(f) }.into());
                }
                Some(info) => return Err(ConfineError::NotRegular { path: dir.join(f), found: info.kind.describe() }.into()),
            }
        }
        if !missing.is_empty() {
            return Err(SynthError::MissingFiles { dir: dir.to_path_buf(), missing });
        }
        if let Some(root) = &root {
            // Nothing anywhere in the package is a symlink, FIFO or device (ONNX Runtime opens
            // the model files and their external data itself, by path), and every external-data
            // file a model names is a plain relative path to a regular file beside it.
            collect_files(root, Path::new(""), &mut Vec::new())?;
            for f in PACKAGE_FILES.iter().filter(|f| f.ends_with(".onnx")) {
                check_external_data(root, Path::new(f))?;
            }
        }
        let config = ModelConfig::read(&dir.join("model.toml"))?;
        let sched_path = dir.join("scheduler/scheduler_config.json");
        let sched_config =
            SchedulerConfig::read(&sched_path).map_err(|source| SynthError::Scheduler { path: sched_path.clone(), source })?;
        let schedule = NoiseSchedule::new(sched_config).map_err(|source| SynthError::Scheduler { path: sched_path, source })?;
        Ok(Self { dir: dir.to_path_buf(), config, schedule })
    }

    /// Path of a package file.
    pub fn file(&self, relative: &str) -> PathBuf {
        self.dir.join(relative)
    }

    /// SHA-256 over every file of the package (recursively, in sorted path order; each file
    /// contributes its relative path, a NUL, its length as 8 little-endian bytes, and its
    /// bytes), hex. Identifies the exact weights a synthetic image came from.
    pub fn content_hash(&self) -> Result<String, SynthError> {
        // Through the opener: every file found below the package folder is a regular file
        // reached without a symlink (a FIFO would block the hash forever; a link would hash,
        // and so reveal, a file elsewhere).
        let root = crate::confine::RootDir::open(&self.dir)?;
        let mut files = Vec::new();
        collect_files(&root, Path::new(""), &mut files)?;
        files.sort();
        let mut hasher = Sha256::new();
        let mut buf = vec![0u8; 1 << 20];
        for rel in files {
            let path = self.dir.join(&rel);
            let io = |source| SynthError::Io { path: path.clone(), source };
            let mut f = root.open_file(&rel)?;
            let len = f.metadata().map_err(io)?.len();
            hasher.update(rel.to_string_lossy().replace('\\', "/").as_bytes());
            hasher.update([0u8]);
            hasher.update(len.to_le_bytes());
            loop {
                let n = f.read(&mut buf).map_err(io)?;
                if n == 0 {
                    break;
                }
                hasher.update(&buf[..n]);
            }
        }
        Ok(hex::encode(hasher.finalize()))
    }
}

/// The external data `model` (a package file) names must lie beside or below it, as regular
/// files reached without a symlink.
fn check_external_data(root: &crate::confine::RootDir, model: &Path) -> Result<(), SynthError> {
    let file = root.path().join(model);
    let bad = |reason: String| SynthError::BadModelFile { file: file.clone(), reason };
    let locations = super::onnx_graph::external_data_locations(root.open_file(model)?)
        .map_err(|e| bad(format!("cannot read its external-data table: {e}")))?;
    let folder = model.parent().unwrap_or(Path::new(""));
    for location in locations {
        match root.open_dir(folder)?.stat(&location) {
            Ok(Some(info)) if info.kind == crate::confine::EntryKind::File => {}
            Ok(Some(info)) => return Err(bad(format!("its external data {location:?} is {}, not a regular file", info.kind.describe()))),
            Ok(None) => return Err(bad(format!("its external data {location:?} is missing"))),
            Err(e) => return Err(bad(format!("its external data {location:?}: {e}"))),
        }
    }
    Ok(())
}

/// The files below `rel` of the package, relative to it; a symlink anywhere is refused, as is
/// anything that is neither a file nor a folder.
fn collect_files(root: &crate::confine::RootDir, rel: &Path, out: &mut Vec<PathBuf>) -> Result<(), SynthError> {
    use crate::confine::{ConfineError, EntryKind};
    for entry in root.entries(rel)? {
        let path = rel.join(&entry.name);
        match entry.kind {
            EntryKind::Folder => collect_files(root, &path, out)?,
            EntryKind::File => out.push(path),
            EntryKind::Symlink => {
                return Err(ConfineError::Symlink { root: root.path().to_path_buf(), path: root.path().join(path) }.into());
            }
            EntryKind::Other => return Err(ConfineError::NotRegular { path: root.path().join(path), found: entry.kind.describe() }.into()),
        }
    }
    Ok(())
}

/// One input or output of a model as the session reports it.
#[cfg(feature = "synth")]
#[derive(Debug, Clone, PartialEq)]
pub struct TensorSpec {
    pub name: String,
    pub ty: TensorElementType,
    /// Dimensions; -1 where dynamic.
    pub shape: Vec<i64>,
}

/// The inputs and outputs of one model file.
#[cfg(feature = "synth")]
#[derive(Debug, Clone)]
pub struct ModelIo {
    pub file: PathBuf,
    pub inputs: Vec<TensorSpec>,
    pub outputs: Vec<TensorSpec>,
}

/// Element types a contract tensor may have.
#[cfg(feature = "synth")]
#[derive(Debug, Clone, Copy)]
pub enum Accept {
    Float32,
    /// int32 or int64 (token ids).
    Ids,
    /// float32, float64, int32 or int64 (timesteps).
    Number,
}

#[cfg(feature = "synth")]
impl Accept {
    fn allows(self, ty: TensorElementType) -> bool {
        use TensorElementType as T;
        match self {
            Accept::Float32 => ty == T::Float32,
            Accept::Ids => matches!(ty, T::Int32 | T::Int64),
            Accept::Number => matches!(ty, T::Float32 | T::Float64 | T::Int32 | T::Int64),
        }
    }
    fn describe(self) -> &'static str {
        match self {
            Accept::Float32 => "float32",
            Accept::Ids => "int32 or int64",
            Accept::Number => "float32, float64, int32 or int64",
        }
    }
}

#[cfg(feature = "synth")]
fn specs(file: &Path, direction: &'static str, outlets: &[ort::value::Outlet]) -> Result<Vec<TensorSpec>, SynthError> {
    outlets
        .iter()
        .map(|o| match o.dtype() {
            ValueType::Tensor { ty, shape, .. } => Ok(TensorSpec { name: o.name().to_string(), ty: *ty, shape: shape.to_vec() }),
            other => Err(SynthError::WrongElementType {
                file: file.to_path_buf(),
                direction,
                tensor: o.name().to_string(),
                found: format!("{other:?}"),
                expected: "a tensor",
            }),
        })
        .collect()
}

#[cfg(feature = "synth")]
impl ModelIo {
    /// Reads the inputs and outputs of a session made from `file`.
    pub fn of(file: &Path, session: &ort::session::Session) -> Result<Self, SynthError> {
        Ok(Self {
            file: file.to_path_buf(),
            inputs: specs(file, "input", session.inputs())?,
            outputs: specs(file, "output", session.outputs())?,
        })
    }

    fn find<'a>(&'a self, list: &'a [TensorSpec], direction: &'static str, name: &str) -> Result<&'a TensorSpec, SynthError> {
        list.iter().find(|s| s.name == name).ok_or_else(|| SynthError::MissingTensor {
            file: self.file.clone(),
            direction,
            tensor: name.to_string(),
            available: list.iter().map(|s| s.name.clone()).collect(),
        })
    }

    /// Checks one tensor: present, of an accepted element type, of one of the accepted ranks.
    pub fn expect(&self, direction: &'static str, name: &str, accept: Accept, ranks: &[usize]) -> Result<&TensorSpec, SynthError> {
        let list = if direction == "input" { &self.inputs } else { &self.outputs };
        let spec = self.find(list, direction, name)?;
        if !accept.allows(spec.ty) {
            return Err(SynthError::WrongElementType {
                file: self.file.clone(),
                direction,
                tensor: name.to_string(),
                found: format!("{:?}", spec.ty),
                expected: accept.describe(),
            });
        }
        if !ranks.contains(&spec.shape.len()) {
            return Err(SynthError::WrongShape {
                file: self.file.clone(),
                direction,
                tensor: name.to_string(),
                found: spec.shape.clone(),
                expected: format!("rank {}", ranks.iter().map(|r| r.to_string()).collect::<Vec<_>>().join(" or ")),
            });
        }
        Ok(spec)
    }

    /// Every input must be one the pipeline feeds.
    pub fn only_inputs(&self, allowed: &[String]) -> Result<(), SynthError> {
        match self.inputs.iter().find(|s| !allowed.contains(&s.name)) {
            Some(extra) => Err(SynthError::UnexpectedInput { file: self.file.clone(), tensor: extra.name.clone() }),
            None => Ok(()),
        }
    }

    /// How many consecutive `{prefix}{i}` tensors (i = 0, 1, ...) there are.
    pub fn count_numbered(&self, direction: &'static str, prefix: &str) -> usize {
        let list = if direction == "input" { &self.inputs } else { &self.outputs };
        (0..).take_while(|i| list.iter().any(|s| s.name == format!("{prefix}{i}"))).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::scheduler::SchedulerKind;

    fn write_toml(text: &str) -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.toml");
        std::fs::write(&path, text).unwrap();
        (dir, path)
    }

    #[test]
    fn model_toml_defaults_and_validation() {
        let (_d, p) = write_toml("name = \"x\"\n");
        let c = ModelConfig::read(&p).unwrap();
        assert_eq!((c.width_px, c.height_px, c.vae_scale_factor), (512, 512, 8));
        assert_eq!(c.hint_encoding, HintEncoding::Rgb01);
        assert!((c.latent_scale - 0.18215).abs() < 1e-7);
        let (_d, p) = write_toml("name = \"x\"\nhint_encoding = \"bgr\"\n");
        let e = ModelConfig::read(&p).unwrap_err();
        assert!(matches!(e, SynthError::BadModelConfig { field: "hint_encoding", .. }), "{e}");
        let (_d, p) = write_toml("name = \"x\"\nresolution = [500, 512]\n");
        assert!(matches!(ModelConfig::read(&p), Err(SynthError::BadModelConfig { field: "resolution", .. })));
        // A size that would abort on allocation is refused when read.
        let (_d, p) = write_toml("name = \"x\"\nresolution = [100000, 100000]\n");
        let e = ModelConfig::read(&p).expect_err("huge resolution");
        assert!(matches!(e, SynthError::BadModelConfig { field: "resolution", .. }) && e.to_string().contains("2048"), "{e}");
        let (_d, p) = write_toml("name = \"x\"\nguidance = 1e30\n");
        assert!(matches!(ModelConfig::read(&p), Err(SynthError::BadModelConfig { field: "guidance", .. })));
        let (_d, p) = write_toml("resolution = [512, 512]\n");
        assert!(matches!(ModelConfig::read(&p), Err(SynthError::ModelToml { .. })));
        assert_eq!((c.sampling_steps, c.guidance, c.eta), (None, None, None));
        assert_eq!(c.sampler, None);
        let (_d, p) = write_toml("name = \"x\"\nsampling_steps = 20\nguidance = 1.0\nsampler = \"dpm++2m\"\neta = 0.5\n");
        let c = ModelConfig::read(&p).unwrap();
        assert_eq!((c.sampling_steps, c.guidance, c.sampler), (Some(20), Some(1.0), Some(SchedulerKind::DpmSolverPp2m)));
        assert_eq!(c.eta, Some(0.5));
        let (_d, p) = write_toml("name = \"x\"\neta = -0.1\n");
        assert!(matches!(ModelConfig::read(&p), Err(SynthError::BadModelConfig { field: "eta", .. })));
        let (_d, p) = write_toml("name = \"x\"\nsampler = \"euler\"\n");
        assert!(matches!(ModelConfig::read(&p), Err(SynthError::BadModelConfig { field: "sampler", .. })));
        let (_d, p) = write_toml("name = \"x\"\nsampling_steps = 0\n");
        assert!(matches!(ModelConfig::read(&p), Err(SynthError::BadModelConfig { field: "sampling_steps", .. })));
        let (_d, p) = write_toml("name = \"x\"\nsampling_steps = 40000000\n");
        let e = ModelConfig::read(&p).expect_err("40,000,000 steps");
        assert!(matches!(e, SynthError::BadModelConfig { field: "sampling_steps", .. }) && e.to_string().contains("1 to 10000"), "{e}");
        let (_d, p) = write_toml("name = \"x\"\nguidance = 0.5\n");
        assert!(matches!(ModelConfig::read(&p), Err(SynthError::BadModelConfig { field: "guidance", .. })));
        // Sampling settings: asked for, else the package's, else the fallback (and DDIM).
        let (_d, p) = write_toml("name = \"x\"\nsampling_steps = 20\nsampler = \"dpm++2m\"\n");
        let c = ModelConfig::read(&p).unwrap();
        let dpm = SchedulerKind::DpmSolverPp2m;
        assert_eq!(c.sampling(None, None, None, None, (50, 9.0)), Sampling { steps: 20, guidance: 9.0, sampler: dpm, eta: 0.0 });
        let asked = c.sampling(Some(4), Some(2.0), Some(SchedulerKind::Ddim), Some(0.3), (50, 9.0));
        assert_eq!(asked, Sampling { steps: 4, guidance: 2.0, sampler: SchedulerKind::Ddim, eta: 0.3 });
        let (_d, p) = write_toml("name = \"x\"\neta = 0.7\n");
        let with_eta = ModelConfig::read(&p).unwrap();
        assert_eq!(with_eta.sampling(None, None, None, None, (50, 9.0)).eta, 0.7);
        assert_eq!(with_eta.sampling(None, None, None, Some(0.0), (50, 9.0)).eta, 0.0);
        let (_d, p) = write_toml("name = \"x\"\n");
        let bare = ModelConfig::read(&p).unwrap();
        let want = Sampling { steps: 50, guidance: 9.0, sampler: SchedulerKind::Ddim, eta: 0.0 };
        assert_eq!(bare.sampling(None, None, None, None, (50, 9.0)), want);
    }

    #[test]
    fn missing_files_are_all_listed() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("model.toml"), "name = \"x\"\n").unwrap();
        let e = ModelPackage::open(dir.path()).unwrap_err();
        match &e {
            SynthError::MissingFiles { missing, .. } => assert_eq!(missing.len(), PACKAGE_FILES.len() - 1),
            other => panic!("unexpected {other}"),
        }
        assert!(e.to_string().contains("unet/model.onnx"), "{e}");
    }

    /// A copy of the tiny test package in a temp folder, with `outside/secret` beside it.
    fn package_copy() -> (tempfile::TempDir, PathBuf) {
        let tmp = tempfile::tempdir().unwrap();
        let pkg = tmp.path().join("pkg");
        let tiny = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tiny-package");
        for f in PACKAGE_FILES {
            std::fs::create_dir_all(pkg.join(f).parent().unwrap()).unwrap();
            std::fs::copy(tiny.join(f), pkg.join(f)).unwrap();
        }
        std::fs::create_dir(tmp.path().join("outside")).unwrap();
        std::fs::write(tmp.path().join("outside/secret"), "sentinel").unwrap();
        (tmp, pkg)
    }

    #[test]
    fn symlinks_and_escaping_external_data_in_a_package_are_refused() {
        let (tmp, pkg) = package_copy();
        ModelPackage::open(&pkg).expect("the copy opens");
        // Any symlink in the package, not only at a file the loader names.
        std::os::unix::fs::symlink(tmp.path().join("outside/secret"), pkg.join("unet/weights.bin")).unwrap();
        let e = ModelPackage::open(&pkg).unwrap_err();
        assert!(matches!(e, SynthError::Confined(crate::confine::ConfineError::Symlink { .. })), "{e}");
        std::fs::remove_file(pkg.join("unet/weights.bin")).unwrap();

        // A model whose initializer keeps its data in a file outside the package.
        let ld = |field: u8, bytes: &[u8]| [vec![(field << 3) | 2, bytes.len() as u8], bytes.to_vec()].concat();
        let entry = |k: &str, v: &str| ld(13, &[ld(1, k.as_bytes()), ld(2, v.as_bytes())].concat());
        let model = |location: &str| ld(7, &ld(5, &[ld(8, b"w"), entry("location", location)].concat()));
        for (location, phrase) in [("../../outside/secret", "not a path below"), ("absent.bin", "missing")] {
            std::fs::write(pkg.join("unet/model.onnx"), model(location)).unwrap();
            let e = ModelPackage::open(&pkg).unwrap_err();
            assert!(matches!(e, SynthError::BadModelFile { .. }) && e.to_string().contains(phrase), "{location}: {e}");
            assert!(!e.to_string().contains("sentinel"), "{e}");
        }
        std::fs::write(pkg.join("unet/weights.bin"), [0u8; 16]).unwrap();
        std::fs::write(pkg.join("unet/model.onnx"), model("weights.bin")).unwrap();
        ModelPackage::open(&pkg).expect("external data beside the model is fine (ONNX Runtime checks the rest)");
    }
}

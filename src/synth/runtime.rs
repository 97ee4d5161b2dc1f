//! Finding and loading ONNX Runtime, and choosing the execution provider.
//!
//! rig links ONNX Runtime at run time (`ort`'s load-dynamic), so the library must be found
//! before any session is made; without it `ort` would panic on first use. Loading a library
//! runs its code, so where it comes from is a trust decision. Search order:
//!
//! 1. the explicit path in [`RuntimeOptions::ort_lib`] (`--ort-lib`; for `rig daemon`, given
//!    once at start, never by a request), a file or a folder;
//! 2. the environment variables `RIG_ORT_LIB`, then `ORT_DYLIB_PATH`;
//! 3. `.rig/onnxruntime/` in the checkout rig was built from (what `scripts/setup.sh` fills
//!    from the PyPI `onnxruntime` wheel), then `onnxruntime/` beside the executable.
//!
//! The current folder is never searched: a library planted in a dataset folder would run in
//! whoever works there. A library found by the search (3) must be owned by the user running
//! rig (or root), as must its folder, and neither may be writable by group or others;
//! otherwise it is refused with [`SynthError::OrtLibraryUntrusted`]. Paths given explicitly
//! (1, 2) are the operator's choice and are not second-guessed. An explicit path or variable
//! that does not exist is an error naming it (rather than quietly using another library).
//!
//! The library is loaded once per process (a log line at `info` says which, and why);
//! [`Runtime::library`] and [`Runtime::origin`] tell, and `rig synth info` prints them.

use std::fmt;
use std::path::{Path, PathBuf};
#[cfg(feature = "synth")]
use std::sync::OnceLock;

#[cfg(feature = "synth")]
use ort::ep::ExecutionProvider;

use super::SynthError;

/// Where ONNX Runtime runs the models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ExecutionProviderKind {
    /// ONNX Runtime's CPU kernels (always available).
    #[default]
    Cpu,
    /// NVIDIA CUDA (needs a CUDA build of ONNX Runtime, e.g. the onnxruntime-gpu wheel).
    Cuda,
    /// NVIDIA TensorRT, falling back to CUDA for unsupported nodes.
    TensorRt,
}

impl fmt::Display for ExecutionProviderKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Cpu => "cpu",
            Self::Cuda => "cuda",
            Self::TensorRt => "tensorrt",
        })
    }
}

impl std::str::FromStr for ExecutionProviderKind {
    type Err = SynthError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "cpu" => Ok(Self::Cpu),
            "cuda" => Ok(Self::Cuda),
            "tensorrt" | "trt" => Ok(Self::TensorRt),
            _ => Err(SynthError::BadRequest {
                field: "provider",
                value: s.to_string(),
                reason: "expected cpu, cuda or tensorrt".to_string(),
            }),
        }
    }
}

/// How to run ONNX Runtime.
#[derive(Debug, Clone, Default)]
pub struct RuntimeOptions {
    /// The library file or its folder; `None` searches (see the module docs).
    pub ort_lib: Option<PathBuf>,
    pub provider: ExecutionProviderKind,
    /// Threads per session for the CPU provider; `None` lets ONNX Runtime choose.
    pub intra_threads: Option<usize>,
    /// Settings of the CUDA provider (also what TensorRT hands its leftover nodes to).
    pub cuda: CudaOptions,
    /// TensorRT's engine cache folder (`--trt-engine-cache`): built engines are kept there and
    /// reused by the next process with the same models and shapes.
    pub trt_engine_cache: Option<PathBuf>,
    /// Run guidance as two passes per step (unconditioned, then conditioned) even where the
    /// graphs take a batch of two: what a package with a fixed batch of 1 gets anyway.
    pub force_two_pass: bool,
    /// Feed each session call from host copies (`Session::run`) instead of I/O binding: the
    /// ControlNet's residuals then travel through host memory every step (for comparison).
    pub without_io_binding: bool,
}

/// cuDNN's search for convolution algorithms (the CUDA provider's `cudnn_conv_algo_search`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ConvSearch {
    /// Time every algorithm on the first run of each shape (ONNX Runtime's default): the
    /// fastest steady state, the slowest first step.
    Exhaustive,
    /// cuDNN's heuristics: no timing runs, a cheaper first step.
    Heuristic,
    /// The one implicit-GEMM algorithm: least memory, no search.
    Default,
}

/// How the CUDA provider's memory arena grows (`arena_extend_strategy`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ArenaExtend {
    /// By doubling (ONNX Runtime's default).
    NextPowerOfTwo,
    /// By what is asked for: less memory held, more allocations.
    SameAsRequested,
}

/// The CUDA provider's options rig exposes; `None` leaves ONNX Runtime's default.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CudaOptions {
    /// The GPU's index (0: the first).
    pub device_id: i32,
    pub conv_search: Option<ConvSearch>,
    pub arena_extend: Option<ArenaExtend>,
    /// The memory arena's limit, bytes.
    pub mem_limit_bytes: Option<usize>,
}

#[cfg(feature = "synth")]
impl CudaOptions {
    fn provider(&self) -> ort::ep::CUDA {
        let mut ep = ort::ep::CUDA::default().with_device_id(self.device_id);
        if let Some(search) = self.conv_search {
            ep = ep.with_conv_algorithm_search(match search {
                ConvSearch::Exhaustive => ort::ep::cuda::ConvAlgorithmSearch::Exhaustive,
                ConvSearch::Heuristic => ort::ep::cuda::ConvAlgorithmSearch::Heuristic,
                ConvSearch::Default => ort::ep::cuda::ConvAlgorithmSearch::Default,
            });
        }
        if let Some(arena) = self.arena_extend {
            ep = ep.with_arena_extend_strategy(match arena {
                ArenaExtend::NextPowerOfTwo => ort::ep::ArenaExtendStrategy::NextPowerOfTwo,
                ArenaExtend::SameAsRequested => ort::ep::ArenaExtendStrategy::SameAsRequested,
            });
        }
        if let Some(limit) = self.mem_limit_bytes {
            ep = ep.with_memory_limit(limit);
        }
        ep
    }
}

/// The loaded runtime: the library it came from and the shared environment.
#[cfg(feature = "synth")]
#[derive(Clone)]
pub struct Runtime {
    pub library: PathBuf,
    /// How the library was chosen (`--ort-lib`, `RIG_ORT_LIB`, `the checkout's .rig/onnxruntime`...).
    pub origin: &'static str,
    environment: ort::environment::Environment,
}

#[cfg(feature = "synth")]
impl fmt::Debug for Runtime {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Runtime").field("library", &self.library).finish_non_exhaustive()
    }
}

#[cfg(feature = "synth")]
static RUNTIME: OnceLock<Runtime> = OnceLock::new();

/// Library file names ONNX Runtime ships under, most specific last (a versioned `.so.1.x.y`
/// is what the PyPI wheel holds).
fn is_library_name(name: &str) -> bool {
    name == "libonnxruntime.so"
        || (name.starts_with("libonnxruntime.so.") && !name.contains("providers"))
        || name == "libonnxruntime.dylib"
        || (name.starts_with("libonnxruntime.") && name.ends_with(".dylib") && !name.contains("providers"))
        || name == "onnxruntime.dll"
}

/// The library inside `dir`, if any (the unversioned name first, then the highest version).
fn library_in_dir(dir: &Path) -> Option<PathBuf> {
    let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
        .ok()?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.is_file() && p.file_name().and_then(|n| n.to_str()).is_some_and(is_library_name))
        .collect();
    found.sort();
    found.iter().find(|p| p.file_name().is_some_and(|n| n == "libonnxruntime.so")).cloned().or(found.pop())
}

/// Resolves a user-given path (file or folder) to the library file.
fn resolve_given(path: &Path, origin: &'static str) -> Result<PathBuf, SynthError> {
    if path.is_file() {
        Ok(path.to_path_buf())
    } else if path.is_dir() {
        library_in_dir(path).ok_or_else(|| SynthError::OrtLibraryNotFound { searched: vec![path.to_path_buf()] })
    } else {
        Err(SynthError::OrtLibraryMissing { path: path.to_path_buf(), origin })
    }
}

/// Finds the ONNX Runtime library (search order in the module docs).
pub fn find_ort_library(explicit: Option<&Path>) -> Result<PathBuf, SynthError> {
    locate_ort_library(explicit).map(|(path, _)| path)
}

/// [`find_ort_library`], with how the library was chosen.
pub fn locate_ort_library(explicit: Option<&Path>) -> Result<(PathBuf, &'static str), SynthError> {
    if let Some(path) = explicit {
        return Ok((resolve_given(path, "--ort-lib")?, "--ort-lib"));
    }
    for var in ["RIG_ORT_LIB", "ORT_DYLIB_PATH"] {
        if let Some(value) = std::env::var_os(var).filter(|v| !v.is_empty()) {
            return Ok((resolve_given(Path::new(&value), var)?, var));
        }
    }
    let mut searched = Vec::new();
    for (dir, origin) in search_dirs() {
        if let Some(lib) = library_in_dir(&dir) {
            check_trusted(&lib)?;
            return Ok((lib, origin));
        }
        searched.push(dir);
    }
    Err(SynthError::OrtLibraryNotFound { searched })
}

/// The folders searched when no library is named, in order (never the current folder).
pub fn search_dirs() -> Vec<(PathBuf, &'static str)> {
    let mut dirs = vec![(Path::new(env!("CARGO_MANIFEST_DIR")).join(".rig/onnxruntime"), "the checkout's .rig/onnxruntime/")];
    if let Some(exe_dir) = std::env::current_exe().ok().and_then(|e| e.parent().map(Path::to_path_buf)) {
        dirs.push((exe_dir.join("onnxruntime"), "onnxruntime/ beside the executable"));
    }
    dirs
}

/// A searched-for library must belong to this user (or root), in a folder that does too,
/// neither writable by group or others: nobody else could have put it there.
fn check_trusted(library: &Path) -> Result<(), SynthError> {
    use std::os::unix::fs::MetadataExt;
    let refuse = |path: &Path, reason: String| SynthError::OrtLibraryUntrusted { path: path.to_path_buf(), reason };
    let file = library.canonicalize().map_err(|e| refuse(library, format!("cannot be resolved: {e}")))?;
    let folder = file.parent().map(Path::to_path_buf).unwrap_or_default();
    // SAFETY: geteuid has no preconditions and cannot fail.
    let me = unsafe { libc::geteuid() };
    for path in [&file, &folder] {
        let meta = std::fs::metadata(path).map_err(|e| refuse(library, format!("{}: {e}", path.display())))?;
        if meta.uid() != me && meta.uid() != 0 {
            return Err(refuse(library, format!("{} belongs to user id {}, not to you ({me}) or root", path.display(), meta.uid())));
        }
        if meta.mode() & 0o022 != 0 {
            return Err(refuse(library, format!("{} is writable by group or others (mode {:o})", path.display(), meta.mode() & 0o777)));
        }
    }
    Ok(())
}

/// Loads ONNX Runtime once per process and returns it. A later call with another library
/// path gets the library already loaded (a process can hold only one).
#[cfg(feature = "synth")]
pub fn init_runtime(opts: &RuntimeOptions) -> Result<Runtime, SynthError> {
    if let Some(rt) = RUNTIME.get() {
        return Ok(rt.clone());
    }
    let (library, origin) = locate_ort_library(opts.ort_lib.as_deref())?;
    let builder = ort::init_from(&library).map_err(|source| SynthError::OrtLoad { path: library.clone(), source })?;
    let environment =
        builder.with_name("rig").build().map_err(|source| SynthError::Ort { context: "creating the environment".to_string(), source })?;
    tracing::info!(library = %library.display(), origin, "ONNX Runtime loaded");
    let rt = Runtime { library, origin, environment };
    Ok(RUNTIME.get_or_init(|| rt).clone())
}

#[cfg(feature = "synth")]
impl Runtime {
    /// Whether the loaded library was built with `provider`.
    pub fn supports(&self, provider: ExecutionProviderKind) -> Result<bool, SynthError> {
        let available = match provider {
            ExecutionProviderKind::Cpu => return Ok(true),
            ExecutionProviderKind::Cuda => ort::ep::CUDA::is_available(),
            ExecutionProviderKind::TensorRt => ort::ep::TensorRT::is_available(),
        };
        available.map_err(|source| SynthError::Ort { context: format!("asking for {provider} support"), source })
    }

    /// Opens one model file as a session on the chosen provider.
    pub fn session(&self, file: &Path, opts: &RuntimeOptions) -> Result<ort::session::Session, SynthError> {
        let ctx = |what: &str| format!("{what} {}", file.display());
        let err = |what: &str| {
            let context = ctx(what);
            move |source: ort::Error<ort::session::builder::SessionBuilder>| SynthError::Ort { context, source: source.into() }
        };
        let mut builder = ort::session::Session::builder(&self.environment)
            .map_err(|source| SynthError::Ort { context: ctx("session builder for"), source })?;
        if let Some(n) = opts.intra_threads {
            builder = builder.with_intra_threads(n).map_err(err("setting threads for"))?;
        }
        if opts.provider != ExecutionProviderKind::Cpu {
            if !self.supports(opts.provider)? {
                return Err(SynthError::ProviderUnavailable { provider: opts.provider, library: self.library.clone() });
            }
            let providers = match opts.provider {
                ExecutionProviderKind::Cuda => vec![opts.cuda.provider().build().error_on_failure()],
                // TensorRT hands the nodes it cannot run to CUDA.
                _ => {
                    let mut trt = ort::ep::TensorRT::default().with_device_id(opts.cuda.device_id);
                    if let Some(dir) = &opts.trt_engine_cache {
                        let dir = dir.display().to_string();
                        trt = trt.with_engine_cache(true).with_engine_cache_path(&dir).with_timing_cache(true).with_timing_cache_path(dir);
                    }
                    vec![trt.build().error_on_failure(), opts.cuda.provider().build()]
                }
            };
            builder = builder.with_execution_providers(providers).map_err(err("registering the provider for"))?;
        }
        builder.commit_from_file(file).map_err(|source| SynthError::BadModelFile {
            file: file.to_path_buf(),
            reason: crate::untrusted::sanitise(&source.to_string()),
        })
    }
}

/// Input values for one session call, by name.
#[cfg(feature = "synth")]
pub(crate) type Inputs = Vec<(String, ort::session::SessionInputValue<'static>)>;

/// A float32 tensor value, in memory from ONNX Runtime's allocator (aligned as its kernels
/// prefer) rather than wrapping the Rust `Vec`.
#[cfg(feature = "synth")]
pub(crate) fn f32_value(shape: &[usize], data: Vec<f32>) -> Result<ort::session::SessionInputValue<'static>, SynthError> {
    f32_tensor(shape, &data).map(Into::into)
}

/// [`f32_value`] as a tensor (to bind to a session input with I/O binding).
#[cfg(feature = "synth")]
pub(crate) fn f32_tensor(shape: &[usize], data: &[f32]) -> Result<ort::value::Tensor<f32>, SynthError> {
    let err = |source| SynthError::Ort { context: "making a float32 tensor".to_string(), source };
    let dims: Vec<i64> = shape.iter().map(|&d| d as i64).collect();
    let mut tensor = ort::value::Tensor::<f32>::new(&ort::memory::Allocator::default(), dims).map_err(err)?;
    let (_, dst) = tensor.try_extract_tensor_mut::<f32>().map_err(err)?;
    if dst.len() != data.len() {
        return Err(SynthError::BadRequest {
            field: "tensor",
            value: format!("{} values", data.len()),
            reason: format!("shape {shape:?} holds {}", dst.len()),
        });
    }
    dst.copy_from_slice(data);
    Ok(tensor)
}

/// A tensor of `ty` (float32, float64, int32 or int64) holding `values`, converted from f64.
#[cfg(feature = "synth")]
pub(crate) fn number_value(
    ty: ort::value::TensorElementType,
    shape: &[usize],
    values: &[f64],
) -> Result<ort::session::SessionInputValue<'static>, SynthError> {
    number_tensor(ty, shape, values).map(Into::into)
}

/// [`number_value`] as a value (to bind to a session input with I/O binding).
#[cfg(feature = "synth")]
pub(crate) fn number_tensor(
    ty: ort::value::TensorElementType,
    shape: &[usize],
    values: &[f64],
) -> Result<ort::value::DynValue, SynthError> {
    use ort::value::{Tensor, TensorElementType as T};
    let shape: Vec<i64> = shape.iter().map(|&d| d as i64).collect();
    let made = match ty {
        T::Float64 => Tensor::from_array((shape, values.to_vec())).map(|t| t.into_dyn()),
        T::Int64 => Tensor::from_array((shape, values.iter().map(|&v| v.round() as i64).collect::<Vec<_>>())).map(|t| t.into_dyn()),
        T::Int32 => Tensor::from_array((shape, values.iter().map(|&v| v.round() as i32).collect::<Vec<_>>())).map(|t| t.into_dyn()),
        _ => Tensor::from_array((shape, values.iter().map(|&v| v as f32).collect::<Vec<_>>())).map(|t| t.into_dyn()),
    };
    made.map_err(|source| SynthError::Ort { context: format!("making a {ty:?} tensor"), source })
}

/// Where a model's outputs stay between session calls under I/O binding: the GPU's memory
/// for CUDA and TensorRT, host memory for the CPU provider.
#[cfg(feature = "synth")]
pub(crate) fn device_memory(opts: &RuntimeOptions) -> Result<ort::memory::MemoryInfo<'static>, SynthError> {
    use ort::memory::{AllocationDevice, AllocatorType, MemoryInfo, MemoryType};
    let made = match opts.provider {
        ExecutionProviderKind::Cpu => MemoryInfo::new(AllocationDevice::CPU, 0, AllocatorType::Device, MemoryType::Default),
        ExecutionProviderKind::Cuda | ExecutionProviderKind::TensorRt => {
            MemoryInfo::new(AllocationDevice::CUDA, opts.cuda.device_id, AllocatorType::Device, MemoryType::Default)
        }
    };
    made.map_err(|source| SynthError::Ort { context: format!("describing {} memory", opts.provider), source })
}

/// Host memory, for an output that must come back to the CPU (the UNet's noise estimate).
#[cfg(feature = "synth")]
pub(crate) fn host_memory() -> Result<ort::memory::MemoryInfo<'static>, SynthError> {
    use ort::memory::{AllocationDevice, AllocatorType, MemoryInfo, MemoryType};
    MemoryInfo::new(AllocationDevice::CPU, 0, AllocatorType::Device, MemoryType::CPUOutput)
        .map_err(|source| SynthError::Ort { context: "describing host memory".to_string(), source })
}

/// A float32 output: its shape and its values (C order).
#[cfg(feature = "synth")]
pub(crate) type ShapedF32 = (Vec<i64>, Vec<f32>);

/// Runs a session and copies the named float32 outputs out, with their shapes.
#[cfg(feature = "synth")]
pub(crate) fn run_f32(
    session: &mut ort::session::Session,
    file: &Path,
    inputs: Inputs,
    output_names: &[String],
) -> Result<Vec<ShapedF32>, SynthError> {
    let outputs = session.run(inputs).map_err(|source| SynthError::Ort { context: format!("running {}", file.display()), source })?;
    output_names
        .iter()
        .map(|name| {
            let value = outputs.get(name.as_str()).ok_or_else(|| SynthError::MissingTensor {
                file: file.to_path_buf(),
                direction: "output",
                tensor: name.clone(),
                available: outputs.keys().map(|k| k.to_string()).collect(),
            })?;
            let (shape, data) = value
                .try_extract_tensor::<f32>()
                .map_err(|source| SynthError::Ort { context: format!("reading output `{name}` of {}", file.display()), source })?;
            Ok((shape.to_vec(), data.to_vec()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn explicit_missing_path_is_named() {
        let e = find_ort_library(Some(Path::new("/nonexistent/libonnxruntime.so"))).unwrap_err();
        assert!(matches!(&e, SynthError::OrtLibraryMissing { origin: "--ort-lib", .. }), "{e}");
        assert!(e.to_string().contains("/nonexistent/libonnxruntime.so"));
    }

    #[test]
    fn empty_folder_has_no_library() {
        let dir = tempfile::tempdir().unwrap();
        let e = find_ort_library(Some(dir.path())).unwrap_err();
        assert!(matches!(e, SynthError::OrtLibraryNotFound { .. }));
        assert!(e.to_string().contains("scripts/setup.sh"));
    }

    #[test]
    fn folder_search_picks_the_library() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("libonnxruntime_providers_shared.so"), b"").unwrap();
        std::fs::write(dir.path().join("libonnxruntime.so.1.31.1"), b"").unwrap();
        let lib = find_ort_library(Some(dir.path())).unwrap();
        assert_eq!(lib.file_name().unwrap(), "libonnxruntime.so.1.31.1");
    }

    #[test]
    fn searched_libraries_must_not_be_writable_by_others() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let lib = dir.path().join("libonnxruntime.so");
        std::fs::write(&lib, b"").unwrap();
        std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
        std::fs::set_permissions(&lib, std::fs::Permissions::from_mode(0o644)).unwrap();
        check_trusted(&lib).expect("owned by us, not writable by others");
        std::fs::set_permissions(&lib, std::fs::Permissions::from_mode(0o666)).unwrap();
        let e = check_trusted(&lib).expect_err("world-writable library");
        assert!(matches!(e, SynthError::OrtLibraryUntrusted { .. }) && e.to_string().contains("writable"), "{e}");
        std::fs::set_permissions(&lib, std::fs::Permissions::from_mode(0o644)).unwrap();
        std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o775)).unwrap();
        assert!(check_trusted(&lib).is_err(), "a group-writable folder");
    }

    #[test]
    fn provider_names_parse() {
        assert_eq!("CUDA".parse::<ExecutionProviderKind>().unwrap(), ExecutionProviderKind::Cuda);
        assert_eq!("trt".parse::<ExecutionProviderKind>().unwrap(), ExecutionProviderKind::TensorRt);
        assert!("tpu".parse::<ExecutionProviderKind>().is_err());
    }
}

//! The pose regressor of `rig eval --downstream`: ResNet18's layout (four stages of two basic
//! residual blocks, batch norm, global average pooling, one linear head) at a chosen width,
//! trained from a seeded random initialisation with AdamW and an L1 loss on standardised
//! labels, with photometric augmentation only (brightness and contrast per image), as
//! MultiDiffSense's downstream protocol does. Built on candle (`candle-core`, `candle-nn`):
//! pure Rust, so it runs inside rig on any machine with no Python or PyTorch.
//!
//! Input: RGB images, `size_px` square, values in [0, 1], laid out `n x 3 x size x size`.
//! Below 128 px the stem is a 3x3 stride-2 convolution (small images); from 128 px it is
//! ResNet18's own 7x7 stride-2 convolution and 3x3 stride-2 max pool.
//!
//! Everything random (initial weights, batch order, augmentation) comes from one seed, so a
//! run is repeatable on one machine (candle's CPU kernels sum in a fixed order).
//!
//! candle is the optional `downstream` feature (on by default): without it [`train_and_predict`]
//! returns [`RegressorError::FeatureMissing`] and everything else here stays.

#[cfg(feature = "downstream")]
use candle_core::{D, DType, Device, Module, Tensor};
#[cfg(feature = "downstream")]
use candle_nn::{
    AdamW, BatchNorm, BatchNormConfig, Conv2d, Conv2dConfig, Linear, ModuleT, Optimizer, ParamsAdamW, VarBuilder, VarMap, batch_norm,
    conv2d_no_bias, linear,
};
#[cfg(feature = "downstream")]
use rand::seq::SliceRandom;
#[cfg(feature = "downstream")]
use rand::{RngExt, SeedableRng};
#[cfg(feature = "downstream")]
use rand_chacha::ChaCha8Rng;

/// Components the regressor predicts, in this order.
pub const OUTPUTS: usize = 3;
/// Channels of an input image.
pub const CHANNELS: usize = 3;
/// From this input size the stem is ResNet18's 7x7 convolution and max pool.
pub const IMAGENET_STEM_FROM_PX: usize = 128;

/// How the regressor is built and trained.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RegressorConfig {
    /// Input images are this many px square.
    pub size_px: usize,
    /// Channels of the first stage (ResNet18: 64); the stages have 1, 2, 4 and 8 times it.
    pub width: usize,
    pub epochs: usize,
    pub batch: usize,
    /// AdamW's learning rate.
    pub learning_rate: f64,
    /// AdamW's decoupled weight decay.
    pub weight_decay: f64,
    /// Brightness (± this, added) and contrast (1 ± this, multiplied about 0.5) drawn per
    /// training image and epoch; 0 turns augmentation off.
    pub photometric_jitter: f32,
}

/// Why training stopped.
#[derive(Debug, thiserror::Error)]
pub enum RegressorError {
    #[error("training data: {0}")]
    Data(String),
    #[cfg(feature = "downstream")]
    #[error("the regressor's tensor arithmetic failed: {0}")]
    Candle(#[from] candle_core::Error),
    #[error(transparent)]
    FeatureMissing(#[from] crate::features::FeatureMissing),
    #[error("training diverged (loss {loss}) at epoch {epoch}")]
    Diverged { epoch: usize, loss: f32 },
}

/// Where the regressor runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TrainDevice {
    /// The CPU (every build).
    Cpu,
    /// The first CUDA GPU: only in a build with the `downstream-cuda` cargo feature.
    Cuda,
}

/// Whether this build trains on CUDA GPUs (the `downstream-cuda` feature).
pub fn cuda_built() -> bool {
    cfg!(feature = "downstream-cuda")
}

#[cfg(feature = "downstream")]
impl TrainDevice {
    fn device(self) -> Result<Device, RegressorError> {
        match self {
            TrainDevice::Cpu => Ok(Device::Cpu),
            TrainDevice::Cuda if cuda_built() => Ok(Device::new_cuda(0)?),
            TrainDevice::Cuda => Err(RegressorError::Data(
                "--device cuda: this rig was built without CUDA training (cargo feature `downstream-cuda`, which needs the CUDA toolkit to build)".into(),
            )),
        }
    }
}

/// Without candle: training is refused, naming the feature.
#[cfg(not(feature = "downstream"))]
pub fn train_and_predict(
    _train: &[f32],
    _labels: &[[f32; OUTPUTS]],
    _test: &[f32],
    _config: &RegressorConfig,
    _seed: u64,
    _device: TrainDevice,
    _progress: impl FnMut(usize, f32),
) -> Result<Vec<[f32; OUTPUTS]>, RegressorError> {
    use crate::features::{Feature, FeatureMissing};
    Err(FeatureMissing { feature: Feature::Downstream, needed_by: "`rig eval --downstream`" }.into())
}

#[cfg(feature = "downstream")]
/// One residual basic block: two 3x3 convolutions with batch norm, and a 1x1 projection on
/// the shortcut where the shape changes.
struct BasicBlock {
    conv1: Conv2d,
    bn1: BatchNorm,
    conv2: Conv2d,
    bn2: BatchNorm,
    shortcut: Option<(Conv2d, BatchNorm)>,
}

#[cfg(feature = "downstream")]
fn bn(channels: usize, vb: VarBuilder) -> candle_core::Result<BatchNorm> {
    batch_norm(channels, BatchNormConfig::default(), vb)
}

#[cfg(feature = "downstream")]
impl BasicBlock {
    fn new(vb: VarBuilder, cin: usize, cout: usize, stride: usize) -> candle_core::Result<Self> {
        let conv = |cin, k, stride, padding, vb| conv2d_no_bias(cin, cout, k, Conv2dConfig { padding, stride, ..Default::default() }, vb);
        let shortcut =
            if stride != 1 || cin != cout { Some((conv(cin, 1, stride, 0, vb.pp("proj"))?, bn(cout, vb.pp("proj_bn"))?)) } else { None };
        Ok(Self {
            conv1: conv(cin, 3, stride, 1, vb.pp("conv1"))?,
            bn1: bn(cout, vb.pp("bn1"))?,
            conv2: conv(cout, 3, 1, 1, vb.pp("conv2"))?,
            bn2: bn(cout, vb.pp("bn2"))?,
            shortcut,
        })
    }

    fn forward(&self, x: &Tensor, train: bool) -> candle_core::Result<Tensor> {
        let y = self.bn1.forward_t(&self.conv1.forward(x)?, train)?.relu()?;
        let y = self.bn2.forward_t(&self.conv2.forward(&y)?, train)?;
        let s = match &self.shortcut {
            Some((conv, norm)) => norm.forward_t(&conv.forward(x)?, train)?,
            None => x.clone(),
        };
        (y + s)?.relu()
    }
}

#[cfg(feature = "downstream")]
/// ResNet18's layout at `width`.
struct ResNet18 {
    stem: Conv2d,
    stem_bn: BatchNorm,
    max_pool: bool,
    blocks: Vec<BasicBlock>,
    head: Linear,
}

#[cfg(feature = "downstream")]
impl ResNet18 {
    fn new(vb: VarBuilder, config: &RegressorConfig) -> candle_core::Result<Self> {
        let w = config.width;
        let imagenet = config.size_px >= IMAGENET_STEM_FROM_PX;
        let (k, padding) = if imagenet { (7, 3) } else { (3, 1) };
        let stem = conv2d_no_bias(CHANNELS, w, k, Conv2dConfig { padding, stride: 2, ..Default::default() }, vb.pp("stem"))?;
        let stem_bn = bn(w, vb.pp("stem_bn"))?;
        let mut blocks = Vec::new();
        let mut cin = w;
        for (stage, mult) in [1, 2, 4, 8].into_iter().enumerate() {
            let cout = w * mult;
            for b in 0..2 {
                let stride = if b == 0 && stage > 0 { 2 } else { 1 };
                blocks.push(BasicBlock::new(vb.pp(format!("stage{stage}.{b}")), cin, cout, stride)?);
                cin = cout;
            }
        }
        let head = linear(cin, OUTPUTS, vb.pp("head"))?;
        Ok(Self { stem, stem_bn, max_pool: imagenet, blocks, head })
    }

    fn forward(&self, x: &Tensor, train: bool) -> candle_core::Result<Tensor> {
        let mut h = self.stem_bn.forward_t(&self.stem.forward(x)?, train)?.relu()?;
        if self.max_pool {
            h = max_pool_3x3_stride_2(&h)?;
        }
        for block in &self.blocks {
            h = block.forward(&h, train)?;
        }
        let pooled = h.mean(D::Minus1)?.mean(D::Minus1)?;
        self.head.forward(&pooled)
    }
}

/// ResNet18's max pool (3x3 window, stride 2, padding 1) as the maximum of nine strided views:
/// candle's own `max_pool2d` has no gradient when windows overlap. Its input comes from a
/// ReLU, so every value is >= 0 and zero padding is the same as padding with -infinity.
#[cfg(feature = "downstream")]
fn max_pool_3x3_stride_2(x: &Tensor) -> candle_core::Result<Tensor> {
    let (n, c, h, w) = x.dims4()?;
    let (ho, wo) = (h.div_ceil(2), w.div_ceil(2));
    // Room for every window: one row (column) before, and enough after for 2 * ho + 1.
    let padded = x.pad_with_zeros(2, 1, 2 * ho + 1 - h)?.pad_with_zeros(3, 1, 2 * wo + 1 - w)?;
    let mut out: Option<Tensor> = None;
    for dy in 0..3 {
        for dx in 0..3 {
            let view = padded
                .narrow(2, dy, 2 * ho)?
                .narrow(3, dx, 2 * wo)?
                .reshape((n, c, ho, 2, wo, 2))?
                .narrow(3, 0, 1)?
                .narrow(5, 0, 1)?
                .reshape((n, c, ho, wo))?;
            out = Some(match out {
                Some(m) => m.maximum(&view)?,
                None => view,
            });
        }
    }
    out.ok_or_else(|| candle_core::Error::Msg("empty pooling window".into()))
}

#[cfg(feature = "downstream")]
/// Sets every variable from `seed`, in name order: convolution weights Kaiming-normal (fan
/// in, as torchvision's ResNet), the head uniform ±1/sqrt(fan in) (PyTorch's `Linear`),
/// batch norm scale 1 and shift 0, running mean 0 and variance 1.
fn seeded_init(vars: &VarMap, seed: u64, device: &Device) -> Result<(), RegressorError> {
    let data = vars.data().lock().map_err(|_| RegressorError::Data("the variable map's lock is poisoned".into()))?;
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for name in names {
        let var = &data[name];
        let dims = var.dims().to_vec();
        let n: usize = dims.iter().product();
        let fan_in: usize = dims.iter().skip(1).product::<usize>().max(1);
        let values: Vec<f32> = if name.contains("bn") && (name.ends_with("weight") || name.ends_with("running_var")) {
            vec![1.0; n]
        } else if name.contains("bn") {
            vec![0.0; n]
        } else if dims.len() == 4 {
            let std = (2.0 / fan_in as f64).sqrt();
            (0..n).map(|_| (normal(&mut rng) * std) as f32).collect()
        } else {
            let fan_in = if dims.len() == 2 { fan_in } else { data_fan_in(&data, name) };
            let bound = 1.0 / (fan_in as f64).sqrt();
            (0..n).map(|_| rng.random_range(-bound..bound) as f32).collect()
        };
        var.set(&Tensor::from_vec(values, dims, device)?)?;
    }
    Ok(())
}

#[cfg(feature = "downstream")]
/// The fan in of a bias: that of the weight beside it.
fn data_fan_in(data: &std::collections::HashMap<String, candle_core::Var>, bias: &str) -> usize {
    let weight = bias.strip_suffix("bias").map(|p| format!("{p}weight"));
    weight.and_then(|w| data.get(&w)).map(|v| v.dims().iter().skip(1).product::<usize>()).unwrap_or(1).max(1)
}

#[cfg(feature = "downstream")]
/// A standard normal draw (Box-Muller).
fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[cfg(feature = "downstream")]
/// Mean and standard deviation of each label component (a constant component gets 1).
fn label_scale(labels: &[[f32; OUTPUTS]]) -> [(f32, f32); OUTPUTS] {
    let n = labels.len().max(1) as f64;
    std::array::from_fn(|c| {
        let mean = labels.iter().map(|l| l[c] as f64).sum::<f64>() / n;
        let var = labels.iter().map(|l| (l[c] as f64 - mean).powi(2)).sum::<f64>() / n;
        let std = var.sqrt();
        (mean as f32, if std > 1e-9 { std as f32 } else { 1.0 })
    })
}

#[cfg(feature = "downstream")]
/// Trains a regressor on `train` (images `n x 3 x size x size`, flattened, values in [0, 1])
/// with `labels`, then predicts the labels of `test`. `progress` is called after each epoch
/// with (epoch, mean training loss).
pub fn train_and_predict(
    train: &[f32],
    labels: &[[f32; OUTPUTS]],
    test: &[f32],
    config: &RegressorConfig,
    seed: u64,
    device: TrainDevice,
    mut progress: impl FnMut(usize, f32),
) -> Result<Vec<[f32; OUTPUTS]>, RegressorError> {
    let pixels = CHANNELS * config.size_px * config.size_px;
    let n = labels.len();
    if n == 0 || train.len() != n * pixels || !test.len().is_multiple_of(pixels) || config.batch == 0 || config.width == 0 {
        return Err(RegressorError::Data(format!(
            "{} training labels, {} training and {} test values for {pixels} values an image, batch {}, width {}",
            n,
            train.len(),
            test.len(),
            config.batch,
            config.width
        )));
    }
    let device = device.device()?;
    let vars = VarMap::new();
    let model = ResNet18::new(VarBuilder::from_varmap(&vars, DType::F32, &device), config)?;
    seeded_init(&vars, seed, &device)?;
    let mut optimiser =
        AdamW::new(vars.all_vars(), ParamsAdamW { lr: config.learning_rate, weight_decay: config.weight_decay, ..Default::default() })?;

    let scale = label_scale(labels);
    let standardised: Vec<f32> = labels.iter().flat_map(|l| (0..OUTPUTS).map(move |c| (l[c] - scale[c].0) / scale[c].1)).collect();
    let size = config.size_px;
    let x_all = Tensor::from_slice(train, (n, CHANNELS, size, size), &device)?;
    let y_all = Tensor::from_vec(standardised, (n, OUTPUTS), &device)?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x05ee_d0fb_a7c4);
    let mut order: Vec<u32> = (0..n as u32).collect();
    for epoch in 0..config.epochs {
        order.shuffle(&mut rng);
        let (mut loss_sum, mut batches) = (0f32, 0usize);
        for chunk in order.chunks(config.batch) {
            // A batch of one has no batch-norm statistics: it joins the previous one's epoch.
            if chunk.len() < 2 {
                continue;
            }
            let idx = Tensor::from_slice(chunk, chunk.len(), &device)?;
            let mut xb = x_all.index_select(&idx, 0)?;
            if config.photometric_jitter > 0.0 {
                let j = config.photometric_jitter;
                let contrast: Vec<f32> = (0..chunk.len()).map(|_| 1.0 + rng.random_range(-j..=j)).collect();
                let brightness: Vec<f32> = (0..chunk.len()).map(|_| rng.random_range(-j..=j)).collect();
                let contrast = Tensor::from_vec(contrast, (chunk.len(), 1, 1, 1), &device)?;
                let brightness = Tensor::from_vec(brightness, (chunk.len(), 1, 1, 1), &device)?;
                xb = ((xb - 0.5)?.broadcast_mul(&contrast)? + 0.5)?.broadcast_add(&brightness)?;
            }
            let yb = y_all.index_select(&idx, 0)?;
            let out = model.forward(&(xb - 0.5)?, true)?;
            let loss = (out - yb)?.abs()?.mean_all()?;
            optimiser.backward_step(&loss)?;
            loss_sum += loss.to_scalar::<f32>()?;
            batches += 1;
        }
        let mean = loss_sum / batches.max(1) as f32;
        if !mean.is_finite() {
            return Err(RegressorError::Diverged { epoch, loss: mean });
        }
        progress(epoch, mean);
    }

    let mut predictions = Vec::with_capacity(test.len() / pixels);
    for chunk in test.chunks(pixels * 32) {
        let m = chunk.len() / pixels;
        let x = Tensor::from_slice(chunk, (m, CHANNELS, size, size), &device)?;
        let out = model.forward(&(x - 0.5)?, false)?.to_vec2::<f32>()?;
        for row in out {
            predictions.push(std::array::from_fn(|c| row.get(c).copied().unwrap_or(f32::NAN) * scale[c].1 + scale[c].0));
        }
    }
    Ok(predictions)
}

#[cfg(all(test, feature = "downstream"))]
mod tests {
    use super::*;

    fn tiny() -> RegressorConfig {
        RegressorConfig { size_px: 16, width: 4, epochs: 30, batch: 8, learning_rate: 3e-3, weight_decay: 0.0, photometric_jitter: 0.0 }
    }

    /// Bright square at a position given by the label: the network must learn where it is.
    fn squares(n: usize, seed: u64) -> (Vec<f32>, Vec<[f32; OUTPUTS]>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let s: usize = 16;
        let (mut images, mut labels) = (Vec::new(), Vec::new());
        for _ in 0..n {
            let (cx, cy) = (rng.random_range(3..13usize), rng.random_range(3..13usize));
            for _ in 0..CHANNELS {
                for y in 0..s {
                    for x in 0..s {
                        images.push(if x.abs_diff(cx) <= 2 && y.abs_diff(cy) <= 2 { 0.9 } else { 0.1 });
                    }
                }
            }
            labels.push([cx as f32, cy as f32, 0.0]);
        }
        (images, labels)
    }

    #[test]
    fn learns_a_position_and_repeats_itself_with_the_same_seed() {
        let (train, labels) = squares(96, 1);
        let (test, truth) = squares(24, 2);
        let config = tiny();
        let a = train_and_predict(&train, &labels, &test, &config, 7, TrainDevice::Cpu, |_, _| {}).expect("train");
        let b = train_and_predict(&train, &labels, &test, &config, 7, TrainDevice::Cpu, |_, _| {}).expect("train");
        assert_eq!(a, b, "one seed, one result");
        let mae: f32 = a.iter().zip(&truth).map(|(p, t)| (p[0] - t[0]).abs()).sum::<f32>() / truth.len() as f32;
        // Guessing the mean (7.5) of a uniform 3..12 gives about 2.5 px.
        assert!(mae < 1.0, "x MAE {mae} px");
        // The constant component stays at its constant.
        assert!(a.iter().all(|p| p[2].abs() < 0.25), "{a:?}");
    }

    #[test]
    fn from_128_px_the_stem_is_resnet18s_own_and_predicts_every_test_image() {
        // 7x7 stride-2 convolution and max pool: 128 -> 64 -> 32, then the stages to 4 x 4.
        let s = IMAGENET_STEM_FROM_PX;
        let config = RegressorConfig { size_px: s, width: 2, epochs: 1, batch: 4, ..tiny() };
        let image = |i: usize| (0..CHANNELS * s * s).map(move |p| ((p * 7 + i * 13) % 97) as f32 / 97.0);
        let train: Vec<f32> = (0..8).flat_map(image).collect();
        let labels: Vec<[f32; OUTPUTS]> = (0..8).map(|i| [i as f32, 0.5 * i as f32, 10.0 * i as f32]).collect();
        let test: Vec<f32> = (8..11).flat_map(image).collect();
        let got = train_and_predict(&train, &labels, &test, &config, 3, TrainDevice::Cpu, |_, _| {}).expect("train");
        assert_eq!(got.len(), 3);
        assert!(got.iter().flatten().all(|v| v.is_finite()), "{got:?}");
    }

    #[test]
    fn the_max_pool_is_torchs_3x3_stride_2_padding_1() {
        // 1 x 1 x 5 x 5, values 0..25: windows centred on rows and columns 0, 2, 4.
        let x = Tensor::arange(0f32, 25.0, &Device::Cpu).and_then(|t| t.reshape((1, 1, 5, 5))).expect("x");
        let got = max_pool_3x3_stride_2(&x).and_then(|t| t.flatten_all()).and_then(|t| t.to_vec1::<f32>()).expect("pool");
        // torch.nn.functional.max_pool2d(torch.arange(25.).reshape(1, 1, 5, 5), 3, 2, 1)
        assert_eq!(got, vec![6.0, 8.0, 9.0, 16.0, 18.0, 19.0, 21.0, 23.0, 24.0]);
        let even = Tensor::arange(0f32, 16.0, &Device::Cpu).and_then(|t| t.reshape((1, 1, 4, 4))).expect("x");
        let got = max_pool_3x3_stride_2(&even).and_then(|t| t.flatten_all()).and_then(|t| t.to_vec1::<f32>()).expect("pool");
        // torch: [[5, 7], [13, 15]]
        assert_eq!(got, vec![5.0, 7.0, 13.0, 15.0]);
    }

    #[test]
    fn refuses_mismatched_data() {
        let config = tiny();
        let err = train_and_predict(&[0.0; 10], &[[0.0; OUTPUTS]], &[], &config, 1, TrainDevice::Cpu, |_, _| {}).unwrap_err();
        assert!(err.to_string().contains("1 training labels, 10 training"), "{err}");
    }
}

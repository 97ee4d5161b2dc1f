//! Prompt text to embeddings: the CLIP tokenizer and the text encoder, with a cache.
//!
//! Tokenisation follows diffusers' Stable Diffusion pipelines: truncate to the encoder's
//! sequence length (77 for CLIP) keeping the start and end tokens, then pad to exactly that
//! length with the end token (`<|endoftext|>`, id 49407 in real CLIP). The `tokenizers`
//! crate's own truncation is used so the end token survives a long prompt (cutting the ids by
//! hand would drop it).
//!
//! Embeddings are cached per distinct prompt text (a fill-missing run repeats the empty
//! negative prompt and often the same pose prompt); the cache is bounded and forgets the
//! oldest entries first.

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use ort::session::Session;
use ort::value::TensorElementType;
use tokenizers::{PaddingDirection, PaddingParams, PaddingStrategy, Tokenizer, TruncationDirection, TruncationParams, TruncationStrategy};

use super::SynthError;
use super::package::{Accept, ModelIo};
use super::runtime::{Inputs, number_value, run_f32};

/// Sequence length when the encoder's input does not fix one (CLIP's).
pub const DEFAULT_SEQUENCE_LEN: usize = 77;
/// How many distinct prompts the cache keeps.
pub const CACHE_CAPACITY: usize = 512;

/// Largest `tokenizer.json` read (CLIP's is about 2 MB).
pub const MAX_TOKENIZER_BYTES: u64 = 64 << 20;

/// CLIP tokenizer set up for the pipeline: fixed length, padded with the end token.
#[derive(Debug, Clone)]
pub struct PromptTokenizer {
    tokenizer: Tokenizer,
    pub sequence_len: usize,
    pub end_id: u32,
    path: PathBuf,
}

impl PromptTokenizer {
    /// Loads `tokenizer.json`; `end_token` is the padding token (CLIP: `<|endoftext|>`).
    pub fn load(path: &Path, end_token: &str, sequence_len: usize) -> Result<Self, SynthError> {
        let bad = |e: &dyn std::fmt::Display| SynthError::Tokenizer {
            path: path.to_path_buf(),
            reason: crate::untrusted::sanitise(&e.to_string()),
        };
        let bytes = crate::untrusted::read_bytes(path, MAX_TOKENIZER_BYTES).map_err(|e| bad(&e))?;
        let mut tokenizer = super::tokenizer_json::parse(&bytes).map_err(|e| bad(&e))?;
        let end_id = tokenizer
            .token_to_id(end_token)
            .ok_or_else(|| SynthError::NoEndToken { path: path.to_path_buf(), token: end_token.to_string() })?;
        tokenizer
            .with_truncation(Some(TruncationParams {
                direction: TruncationDirection::Right,
                max_length: sequence_len,
                strategy: TruncationStrategy::LongestFirst,
                stride: 0,
            }))
            .map_err(|e| bad(&e))?;
        tokenizer.with_padding(Some(PaddingParams {
            strategy: PaddingStrategy::Fixed(sequence_len),
            direction: PaddingDirection::Right,
            pad_to_multiple_of: None,
            pad_id: end_id,
            pad_type_id: 0,
            pad_token: end_token.to_string(),
        }));
        let loaded = Self { tokenizer, sequence_len, end_id, path: path.to_path_buf() };
        // One encode at load: a tokenizer the crate cannot run is refused with the package,
        // not at the first prompt of a job.
        loaded.ids("a")?;
        Ok(loaded)
    }

    /// The ids of one prompt, exactly `sequence_len` long.
    pub fn ids(&self, prompt: &str) -> Result<Vec<u32>, SynthError> {
        let enc = super::tokenizer_json::encode(&self.tokenizer, prompt)
            .map_err(|e| SynthError::Tokenizer { path: self.path.clone(), reason: crate::untrusted::sanitise(&e) })?;
        let mut ids = enc.get_ids().to_vec();
        // Fixed padding and truncation already give this length; keep the invariant explicit
        // for tokenizers whose post-processor adds more than truncation reserved.
        ids.resize(self.sequence_len, self.end_id);
        Ok(ids)
    }
}

/// The text encoder session with its tokenizer and embedding cache.
pub struct TextEncoder {
    pub tokenizer: PromptTokenizer,
    session: Session,
    file: PathBuf,
    ids_type: TensorElementType,
    /// Width of one token's embedding (768 for CLIP ViT-L/14).
    pub hidden_size: usize,
    cache: HashMap<String, Arc<[f32]>>,
    order: VecDeque<String>,
}

impl std::fmt::Debug for TextEncoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TextEncoder").field("file", &self.file).field("hidden_size", &self.hidden_size).finish_non_exhaustive()
    }
}

impl TextEncoder {
    /// Checks the session against the contract (`input_ids` [B, L] int32|int64 ->
    /// `last_hidden_state` [B, L, D] float32) and loads the tokenizer.
    pub fn new(session: Session, file: &Path, tokenizer_path: &Path, end_token: &str) -> Result<Self, SynthError> {
        let io = ModelIo::of(file, &session)?;
        let ids = io.expect("input", "input_ids", Accept::Ids, &[2])?.clone();
        io.only_inputs(&["input_ids".to_string()])?;
        let out = io.expect("output", "last_hidden_state", Accept::Float32, &[3])?;
        let sequence_len = match ids.shape[1] {
            n if n > 0 => n as usize,
            _ => DEFAULT_SEQUENCE_LEN,
        };
        let hidden_size = match out.shape[2] {
            n if n > 0 => n as usize,
            _ => 0, // learnt from the first run
        };
        let tokenizer = PromptTokenizer::load(tokenizer_path, end_token, sequence_len)?;
        Ok(Self {
            tokenizer,
            session,
            file: file.to_path_buf(),
            ids_type: ids.ty,
            hidden_size,
            cache: HashMap::new(),
            order: VecDeque::new(),
        })
    }

    /// Embeddings `[L * D]` of each prompt, from the cache or from one batched encoder call for
    /// the ones not cached.
    pub fn encode(&mut self, prompts: &[&str]) -> Result<Vec<Arc<[f32]>>, SynthError> {
        let mut todo: Vec<&str> = Vec::new();
        for p in prompts {
            if !self.cache.contains_key(*p) && !todo.contains(p) {
                todo.push(p);
            }
        }
        let mut fresh: HashMap<&str, Arc<[f32]>> = HashMap::new();
        if !todo.is_empty() {
            let len = self.tokenizer.sequence_len;
            let mut ids = Vec::with_capacity(todo.len() * len);
            for p in &todo {
                ids.extend(self.tokenizer.ids(p)?.into_iter().map(|i| i as f64));
            }
            let inputs: Inputs = vec![("input_ids".to_string(), number_value(self.ids_type, &[todo.len(), len], &ids)?)];
            let mut out = run_f32(&mut self.session, &self.file, inputs, &["last_hidden_state".to_string()])?;
            let (shape, data) = out.pop().unwrap_or_default();
            let per = data.len() / todo.len();
            if shape.len() != 3 || shape[0] as usize != todo.len() || shape[1] as usize != len || per * todo.len() != data.len() {
                return Err(SynthError::UnexpectedOutputShape {
                    file: self.file.clone(),
                    tensor: "last_hidden_state".to_string(),
                    found: shape,
                    expected: vec![todo.len() as i64, len as i64, -1],
                });
            }
            self.hidden_size = shape[2] as usize;
            for (i, p) in todo.iter().enumerate() {
                let embedding: Arc<[f32]> = data[i * per..(i + 1) * per].into();
                fresh.insert(p, embedding.clone());
                self.insert(p.to_string(), embedding);
            }
        }
        // From this call's results first: a batch of more distinct prompts than the cache holds
        // evicts some of its own before they are returned.
        Ok(prompts.iter().filter_map(|p| fresh.get(p).or_else(|| self.cache.get(*p)).cloned()).collect())
    }

    fn insert(&mut self, prompt: String, embedding: Arc<[f32]>) {
        if self.order.len() >= CACHE_CAPACITY {
            // Forget the oldest prompt, but never the empty one: every guided image uses it.
            if let Some(old) = self.order.iter().position(|p| !p.is_empty()).and_then(|i| self.order.remove(i)) {
                self.cache.remove(&old);
            }
        }
        self.order.push_back(prompt.clone());
        self.cache.insert(prompt, embedding);
    }

    /// Number of prompts cached.
    pub fn cached(&self) -> usize {
        self.cache.len()
    }
}

//! Parquet files of a bounded size: [`RollingFiles`] writes rows into
//! `<kind>/chunk-CCC/file-FFF.parquet` and starts the next file before a row would take the
//! one in progress past the bound, as LeRobot v3 rolls its data and episode files
//! (`data_files_size_in_mb`, `chunks_size`).
//!
//! The bound is kept, not aimed at: before each row, the bytes already written, the row group
//! in progress, the row and a generous estimate of what closing the file adds (the page indexes
//! and the footer, which grow with the row groups and pages) must fit. A file that still ends
//! up over the bound is an error, never a file left so. The writer holds at most one row group
//! in memory (its bound is the writer properties' `max_row_group_bytes`).

use std::fs::File;
use std::path::{Path, PathBuf};

use arrow_array::RecordBatch;
use arrow_schema::{DataType, Field, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::file::properties::WriterProperties;

use super::error::{LerobotError, io_err, write_err};

/// Files per chunk folder (LeRobot's default `chunks_size`).
pub const CHUNKS_SIZE: u64 = 1000;
/// What closing a file adds besides its row groups' metadata: the schema, key-value metadata
/// (the arrow schema) and the magic numbers, bytes.
const FOOTER_BASE_BYTES: u64 = 16 << 10;
/// Footer bytes per column chunk (one per leaf column and row group): the column's path, its
/// offsets and sizes, and statistics of at most 64-byte values twice, rounded up generously.
const FOOTER_PER_CHUNK_BYTES: u64 = 512;
/// Page index bytes per page (an offset-index entry and a column-index entry with min and max
/// of at most 64 bytes each).
const PAGE_INDEX_PER_PAGE_BYTES: u64 = 192;
/// Pages are at most 1 MiB (the writer's default data page size limit).
const PAGE_BYTES: u64 = 1 << 20;

/// The relative path of file `file_index` of `kind` (`data`, `meta/episodes`).
pub fn chunk_file(kind: &str, file_index: u64) -> String {
    format!("{kind}/chunk-{:03}/file-{:03}.parquet", file_index / CHUNKS_SIZE, file_index % CHUNKS_SIZE)
}

/// A parquet file being written, with the path its errors name.
pub struct ParquetOut {
    path: PathBuf,
    writer: ArrowWriter<File>,
    /// Leaf columns of the schema: column chunks per row group.
    leaves: u64,
}

impl ParquetOut {
    pub fn create(path: &Path, schema: SchemaRef, props: WriterProperties) -> Result<Self, LerobotError> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(io_err("creating", dir))?;
        }
        let leaves = schema.fields().iter().map(|f| leaf_columns(f)).sum();
        let file = File::create(path).map_err(io_err("creating", path))?;
        let writer = ArrowWriter::try_new(file, schema, Some(props)).map_err(|e| write_err(path, e))?;
        Ok(Self { path: path.to_path_buf(), writer, leaves })
    }
    pub fn write(&mut self, batch: &RecordBatch) -> Result<(), LerobotError> {
        self.writer.write(batch).map_err(|e| write_err(&self.path, e))
    }
    /// Ends the row group in progress.
    pub fn end_row_group(&mut self) -> Result<(), LerobotError> {
        self.writer.flush().map_err(|e| write_err(&self.path, e))
    }
    /// The file's size if a row of `row_bytes` were added and the file closed, over-estimated:
    /// the row may start a row group of its own and every page may carry a full index entry.
    fn projected_bytes(&self, row_bytes: u64) -> u64 {
        let body = self.writer.bytes_written() as u64 + self.writer.in_progress_size() as u64 + row_bytes;
        // Flushed row groups, the one in progress, and one the row may start.
        let row_groups = self.writer.flushed_row_groups().len() as u64 + 2;
        let chunks = row_groups * self.leaves;
        let pages = chunks + body / PAGE_BYTES;
        body + FOOTER_BASE_BYTES + chunks * FOOTER_PER_CHUNK_BYTES + pages * PAGE_INDEX_PER_PAGE_BYTES
    }
    /// Writes the footer and syncs the file; returns its size.
    pub fn close(self) -> Result<u64, LerobotError> {
        let file = self.writer.into_inner().map_err(|e| write_err(&self.path, e))?;
        file.sync_all().map_err(io_err("syncing", &self.path))?;
        Ok(file.metadata().map_err(io_err("reading", &self.path))?.len())
    }
}

/// The parquet leaf columns (column chunks per row group) of a field.
fn leaf_columns(field: &Field) -> u64 {
    match field.data_type() {
        DataType::Struct(children) => children.iter().map(|c| leaf_columns(c)).sum(),
        DataType::List(child) | DataType::LargeList(child) | DataType::FixedSizeList(child, _) => leaf_columns(child),
        _ => 1,
    }
}

/// Size-bounded parquet files of one kind, written one after another.
pub struct RollingFiles {
    root: PathBuf,
    kind: &'static str,
    bound_bytes: u64,
    props: WriterProperties,
    current: Option<ParquetOut>,
    /// The index of the next file to open.
    next_index: u64,
    /// The files written, relative to `root`, with their sizes.
    files: Vec<(String, u64)>,
}

impl RollingFiles {
    /// Files `root/<kind>/chunk-CCC/file-FFF.parquet` of at most `bound_bytes` each.
    pub fn new(root: &Path, kind: &'static str, bound_bytes: u64, props: WriterProperties) -> Self {
        Self { root: root.to_path_buf(), kind, bound_bytes, props, current: None, next_index: 0, files: Vec::new() }
    }

    /// Makes room for a row of about `row_bytes` (of `schema`): opens the first file, or
    /// closes the file in progress and opens the next one when the row would take it past the
    /// bound. Returns whether the row starts a new file; [`LerobotError::RowTooLarge`] when
    /// the row does not fit even an empty file.
    pub fn make_room(&mut self, row_bytes: u64, schema: &SchemaRef) -> Result<bool, LerobotError> {
        match &self.current {
            Some(out) if out.projected_bytes(row_bytes) <= self.bound_bytes => return Ok(false),
            Some(_) => self.close_current()?,
            None => {}
        }
        let rel = chunk_file(self.kind, self.next_index);
        let out = ParquetOut::create(&self.root.join(&rel), schema.clone(), self.props.clone())?;
        self.next_index += 1;
        let fits = out.projected_bytes(row_bytes) <= self.bound_bytes;
        self.files.push((rel, 0));
        self.current = Some(out);
        if fits { Ok(true) } else { Err(LerobotError::RowTooLarge { kind: self.kind, row_bytes, bound_bytes: self.bound_bytes }) }
    }

    /// The index of the file in progress (its chunk is `index / CHUNKS_SIZE`).
    pub fn file_index(&self) -> u64 {
        self.next_index.saturating_sub(1)
    }

    /// Writes rows into the file in progress ([`make_room`](Self::make_room) first).
    pub fn write(&mut self, batch: &RecordBatch) -> Result<(), LerobotError> {
        match &mut self.current {
            Some(out) => out.write(batch),
            None => Err(write_err(&self.root.join(self.kind), "no file open (make_room first)")),
        }
    }

    /// Ends the row group in progress, if any.
    pub fn end_row_group(&mut self) -> Result<(), LerobotError> {
        match &mut self.current {
            Some(out) => out.end_row_group(),
            None => Ok(()),
        }
    }

    fn close_current(&mut self) -> Result<(), LerobotError> {
        let Some(out) = self.current.take() else { return Ok(()) };
        let path = out.path.clone();
        let size = out.close()?;
        if size > self.bound_bytes {
            return Err(write_err(&path, format!("{size} bytes, over the bound of {} bytes", self.bound_bytes)));
        }
        if let Some(last) = self.files.last_mut() {
            last.1 = size;
        }
        Ok(())
    }

    /// Closes the file in progress; returns every file written (relative path, bytes).
    pub fn finish(mut self) -> Result<Vec<(String, u64)>, LerobotError> {
        self.close_current()?;
        Ok(self.files)
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{BinaryArray, Int64Array};
    use arrow_schema::Schema;

    use super::*;

    fn batch(schema: &SchemaRef, id: i64, bytes: &[u8]) -> RecordBatch {
        RecordBatch::try_new(schema.clone(), vec![Arc::new(Int64Array::from(vec![id])), Arc::new(BinaryArray::from_iter_values([bytes]))])
            .expect("batch")
    }

    #[test]
    fn files_roll_before_the_bound_and_a_row_too_large_is_refused() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let schema: SchemaRef =
            Arc::new(Schema::new(vec![Field::new("id", DataType::Int64, true), Field::new("blob", DataType::Binary, true)]));
        let props = WriterProperties::builder().set_max_row_group_bytes(Some(64 << 10)).set_dictionary_enabled(false).build();
        let bound = 1_000_000;
        let mut files = RollingFiles::new(tmp.path(), "data", bound, props.clone());
        let mut starts = 0;
        for id in 0..40 {
            // 100 kB rows that do not compress (there is no codec) nor repeat.
            let blob: Vec<u8> = (0..100_000u32).map(|i| (i.wrapping_mul(2654435761).wrapping_add(id as u32 * 97) >> 13) as u8).collect();
            if files.make_room(blob.len() as u64 + 64, &schema).expect("room") {
                starts += 1;
            }
            files.write(&batch(&schema, id, &blob)).expect("write");
        }
        let written = files.finish().expect("finish");
        assert_eq!(written.len(), starts);
        assert!(written.len() >= 5, "4 MB in files of 1 MB: {written:?}");
        for (rel, size) in &written {
            let on_disk = std::fs::metadata(tmp.path().join(rel)).expect("file").len();
            assert_eq!(*size, on_disk);
            assert!(on_disk <= bound, "{rel}: {on_disk} bytes");
            // Not wastefully small either: the estimate of the footer is generous, not absurd.
            assert!(on_disk >= bound / 2 || rel == &written.last().expect("last").0, "{rel}: {on_disk} bytes");
        }
        assert_eq!(written[1].0, "data/chunk-000/file-001.parquet");

        let mut small = RollingFiles::new(&tmp.path().join("small"), "data", 50_000, props);
        let err = small.make_room(60_000, &schema).expect_err("a row larger than a file");
        assert!(matches!(err, LerobotError::RowTooLarge { row_bytes: 60_000, bound_bytes: 50_000, .. }), "{err}");
    }
}

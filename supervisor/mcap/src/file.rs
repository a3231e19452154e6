//! An MCAP file being written: chunked, LZ4-compressed, with the `ros2` profile.

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::Path;

/// The writer of one file.
pub type Writer = mcap::Writer<BufWriter<std::fs::File>>;

/// An MCAP file being written. Its per-message path is a concrete function of this crate, so
/// the MCAP writer's generic code (records, chunks, compression) is compiled optimised here.
pub struct McapFile {
    w: Writer,
}

impl McapFile {
    /// A new file at `path` (replacing one there), written by `library`.
    pub fn create(path: &Path, library: &str) -> Result<Self, mcap::McapError> {
        Self::over(std::fs::File::create(path)?, library)
    }

    /// The file written into `file` (new and empty: a temporary file that becomes the output
    /// once [`McapFile::close`] succeeds), by `library`.
    pub fn over(file: std::fs::File, library: &str) -> Result<Self, mcap::McapError> {
        // 4 MiB chunks: a day-long soak's chunk index (what the writer keeps in memory for the
        // summary) stays in the megabytes; a run killed outright loses the chunk being filled.
        let w = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            .chunk_size(Some(4 << 20))
            .profile("ros2")
            .library(library)
            .create(BufWriter::new(file))?;
        Ok(McapFile { w })
    }

    /// Registers a schema; its id.
    pub fn add_schema(
        &mut self,
        name: &str,
        encoding: &str,
        data: &[u8],
    ) -> Result<u16, mcap::McapError> {
        self.w.add_schema(name, encoding, data)
    }

    /// Registers a channel on `topic`; its id.
    pub fn add_channel(
        &mut self,
        schema: u16,
        topic: &str,
        encoding: &str,
    ) -> Result<u16, mcap::McapError> {
        self.w
            .add_channel(schema, topic, encoding, &BTreeMap::new())
    }

    /// Message `sequence` on `channel`, logged and published at `t_ns` (ns).
    pub fn write(
        &mut self,
        channel: u16,
        sequence: u32,
        t_ns: u64,
        data: &[u8],
    ) -> Result<(), mcap::McapError> {
        self.w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: channel,
                sequence,
                log_time: t_ns,
                publish_time: t_ns,
            },
            data,
        )
    }

    /// Ends the file (its summary and footer) and hands back the open file, every byte written
    /// to it: an error here (a full disk) is returned, where dropping the writer would ignore it.
    pub fn close(mut self) -> Result<std::fs::File, mcap::McapError> {
        self.w.finish()?;
        self.w
            .into_inner()
            .into_inner()
            .map_err(|e| mcap::McapError::Io(e.into_error()))
    }

    /// The writer itself, for what a file gets once (attachments, metadata, the summary).
    pub fn writer(&mut self) -> &mut Writer {
        &mut self.w
    }
}

//! `repair`: rewrite a recording cut short (recorder killed, disk full) or with damaged
//! chunks into a complete file with summary, chunk and message indexes, statistics and a
//! fresh `rosbag2` metadata record. Every message that could be read is kept with its
//! channel id, sequence and times.

use crate::channels::*;
use crate::error::RecordingError;
use crate::read::{scan, Event};
use crate::writer::TopicCount;
use mcap::records::{MessageHeader, Metadata};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Serialize)]
pub struct RepairReport {
    pub input: PathBuf,
    pub output: PathBuf,
    pub messages: u64,
    pub channels: usize,
    pub attachments: usize,
    pub metadata: usize,
    /// Why the input's scan stopped early (None: the input was readable to its end).
    pub input_stopped_early: Option<String>,
    pub skipped_chunks: usize,
    pub bytes_in: u64,
    pub bytes_out: u64,
}

/// Rewrites `path` into `out` (a different file; written to `out.partial` then renamed).
pub fn repair(path: &Path, out: &Path) -> Result<RepairReport, RecordingError> {
    if path == out
        || (out.exists() && std::fs::canonicalize(path).ok() == std::fs::canonicalize(out).ok())
    {
        return Err(RecordingError::write(
            out,
            "repair output must be a different file than its input",
        ));
    }
    let tmp = out.with_extension("mcap.partial");
    let file = std::fs::File::create(&tmp).map_err(|e| RecordingError::io(&tmp, e))?;
    let werr = |e: mcap::McapError| RecordingError::write(out, e);
    let mut writer = mcap::WriteOptions::new()
        .profile(PROFILE)
        .library(format!(
            "arthrosim-recordings {} (repair)",
            env!("CARGO_PKG_VERSION")
        ))
        .compression(Some(mcap::Compression::Zstd))
        .compression_threads(0)
        .create(BufWriter::new(file))
        .map_err(werr)?;

    // input channel id → (schema id in output) once registered
    let mut registered: BTreeMap<u16, u16> = BTreeMap::new();
    let mut counts: BTreeMap<u16, u64> = BTreeMap::new();
    let mut bounds: Option<(u64, u64)> = None;
    let (mut attachments, mut metadata) = (0usize, 0usize);

    fn register(
        writer: &mut mcap::Writer<BufWriter<std::fs::File>>,
        registered: &mut BTreeMap<u16, u16>,
        c: &crate::read::ChannelInfo,
    ) -> Result<(), mcap::McapError> {
        if registered.contains_key(&c.id) {
            return Ok(());
        }
        let schema_id =
            writer.add_schema(&c.schema_name, &c.schema_encoding, c.schema_text.as_bytes())?;
        writer.add_channel_with_id(c.id, schema_id, &c.topic, &c.message_encoding, &c.metadata)?;
        registered.insert(c.id, schema_id);
        Ok(())
    }

    let outcome = scan(path, &mut |event| {
        match event {
            Event::Message {
                channel,
                header,
                data,
            } => {
                register(&mut writer, &mut registered, channel).map_err(werr)?;
                writer
                    .write_to_known_channel(
                        &MessageHeader {
                            channel_id: channel.id,
                            ..header
                        },
                        data,
                    )
                    .map_err(werr)?;
                *counts.entry(channel.id).or_insert(0) += 1;
                bounds = Some(match bounds {
                    None => (header.log_time, header.log_time),
                    Some((a, b)) => (a.min(header.log_time), b.max(header.log_time)),
                });
            }
            Event::Metadata(m) => {
                // The rosbag2 record is regenerated below with the repaired counts.
                if m.name != ROSBAG2_METADATA {
                    writer.write_metadata(m).map_err(werr)?;
                    metadata += 1;
                }
            }
            Event::Attachment {
                name,
                media_type,
                log_time,
                data,
            } => {
                writer
                    .attach(&mcap::Attachment {
                        log_time,
                        create_time: log_time,
                        name: name.to_string(),
                        media_type: media_type.to_string(),
                        data: std::borrow::Cow::Borrowed(data),
                    })
                    .map_err(werr)?;
                attachments += 1;
            }
        }
        Ok(())
    });
    let outcome = match outcome {
        Ok(o) => o,
        Err(e) => {
            drop(writer);
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
    };
    for c in outcome.channels.values() {
        register(&mut writer, &mut registered, c).map_err(werr)?;
    }
    let topics: Vec<TopicCount> = outcome
        .channels
        .values()
        .map(|c| TopicCount {
            topic: c.topic.clone(),
            type_name: c.schema_name.clone(),
            count: counts.get(&c.id).copied().unwrap_or(0),
        })
        .collect();
    let (start, end) = bounds.unwrap_or((0, 0));
    let file_name = out
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default();
    let mut rosbag2 = BTreeMap::new();
    rosbag2.insert(
        "serialized_metadata".to_string(),
        crate::rosbag2::metadata_yaml(&file_name, &topics, start, end),
    );
    rosbag2.insert(
        "ROS_DISTRO".to_string(),
        crate::rosbag2::ROS_DISTRO.to_string(),
    );
    writer
        .write_metadata(&Metadata {
            name: ROSBAG2_METADATA.to_string(),
            metadata: rosbag2,
        })
        .map_err(werr)?;
    writer.finish().map_err(werr)?;
    let mut inner = writer.into_inner();
    std::io::Write::flush(&mut inner).map_err(|e| RecordingError::io(&tmp, e))?;
    drop(inner);
    std::fs::rename(&tmp, out).map_err(|e| RecordingError::io(out, e))?;
    let bytes_in = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    let bytes_out = std::fs::metadata(out).map(|m| m.len()).unwrap_or(0);
    Ok(RepairReport {
        input: path.to_path_buf(),
        output: out.to_path_buf(),
        messages: counts.values().sum(),
        channels: outcome.channels.len(),
        attachments,
        metadata,
        input_stopped_early: outcome.stopped_early,
        skipped_chunks: outcome.skipped_chunks.len(),
        bytes_in,
        bytes_out,
    })
}

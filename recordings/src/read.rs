//! Reading recordings: a tolerant linear scan (works on files cut short by `kill -9`: every
//! complete chunk is read, the torn tail is reported), and `info`.

use crate::channels::*;
use crate::error::RecordingError;
use mcap::read::LinearReader;
use mcap::records::{MessageHeader, Metadata, Record};
use msgs::ros::{self, RosMessage};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One channel as found in the file.
#[derive(Debug, Clone, Serialize)]
pub struct ChannelInfo {
    pub id: u16,
    pub topic: String,
    pub schema_name: String,
    pub schema_encoding: String,
    pub schema_text: String,
    pub message_encoding: String,
    pub metadata: BTreeMap<String, String>,
}

/// What the scan hands to its visitor, in file order.
pub enum Event<'a> {
    Message {
        channel: &'a ChannelInfo,
        header: MessageHeader,
        data: &'a [u8],
    },
    Metadata(&'a Metadata),
    Attachment {
        name: &'a str,
        media_type: &'a str,
        log_time: u64,
        data: &'a [u8],
    },
}

/// How a scan went.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ScanOutcome {
    pub profile: String,
    pub library: String,
    pub channels: BTreeMap<u16, ChannelInfo>,
    /// Data end record seen (a cleanly closed file).
    pub data_end: bool,
    /// Footer and summary present.
    pub footer: bool,
    /// Why reading stopped before the end of the file (torn tail after `kill -9`, corruption).
    pub stopped_early: Option<String>,
    /// Chunks that could not be decoded (bad CRC, bad compression) and were skipped.
    pub skipped_chunks: Vec<String>,
    /// Messages whose channel was never declared (skipped).
    pub orphan_messages: u64,
    pub messages: u64,
}

/// Largest uncompressed chunk accepted (a corrupt size field must not make us allocate GBs).
const MAX_CHUNK_BYTES: u64 = 1 << 30;

/// Reads the whole file.
pub fn load(path: &Path) -> Result<Vec<u8>, RecordingError> {
    std::fs::read(path).map_err(|e| RecordingError::io(path, e))
}

struct Scanner<'v> {
    path: PathBuf,
    schemas: BTreeMap<u16, (String, String, String)>,
    out: ScanOutcome,
    visit: &'v mut dyn FnMut(Event<'_>) -> Result<(), RecordingError>,
}

impl Scanner<'_> {
    /// Handles a record found at top level or inside a chunk.
    fn record(&mut self, record: Record<'_>, in_chunk: bool) -> Result<(), RecordingError> {
        match record {
            Record::Header(h) => {
                if in_chunk {
                    return Ok(());
                }
                if h.profile != PROFILE {
                    return Err(RecordingError::WrongProfile {
                        path: self.path.clone(),
                        found: h.profile,
                    });
                }
                self.out.profile = h.profile;
                self.out.library = h.library;
            }
            Record::Schema { header, data } => {
                let text = String::from_utf8_lossy(&data).into_owned();
                self.schemas
                    .insert(header.id, (header.name, header.encoding, text));
            }
            Record::Channel(c) => {
                if self.out.channels.contains_key(&c.id) {
                    return Ok(());
                }
                let (schema_name, schema_encoding, schema_text) =
                    match self.schemas.get(&c.schema_id) {
                        Some(s) => s.clone(),
                        None => {
                            return Err(RecordingError::UnknownSchema {
                                path: self.path.clone(),
                                topic: c.topic,
                                schema: format!("id {}", c.schema_id),
                                encoding: String::new(),
                            })
                        }
                    };
                if schema_encoding != SCHEMA_ENCODING || c.message_encoding != MESSAGE_ENCODING {
                    return Err(RecordingError::UnknownSchema {
                        path: self.path.clone(),
                        topic: c.topic,
                        schema: schema_name,
                        encoding: format!("{schema_encoding}/{}", c.message_encoding),
                    });
                }
                self.out.channels.insert(
                    c.id,
                    ChannelInfo {
                        id: c.id,
                        topic: c.topic,
                        schema_name,
                        schema_encoding,
                        schema_text,
                        message_encoding: c.message_encoding,
                        metadata: c.metadata,
                    },
                );
            }
            Record::Message { header, data } => match self.out.channels.get(&header.channel_id) {
                Some(channel) => {
                    self.out.messages += 1;
                    (self.visit)(Event::Message {
                        channel,
                        header,
                        data: &data,
                    })?;
                }
                None => self.out.orphan_messages += 1,
            },
            Record::Chunk { header, data } => {
                if in_chunk {
                    return Ok(());
                }
                if header.uncompressed_size > MAX_CHUNK_BYTES
                    || header.uncompressed_size
                        > (data.len() as u64).saturating_mul(1000) + (1 << 20)
                {
                    self.out.skipped_chunks.push(format!(
                        "chunk claims {} bytes uncompressed from {} compressed",
                        header.uncompressed_size,
                        data.len()
                    ));
                    return Ok(());
                }
                // Decompress and verify the CRC before parsing: the records inside are then
                // parsed from a buffer of known size (lengths beyond it are errors, not
                // allocations).
                let uncompressed = match header.compression.as_str() {
                    "" => data.into_owned(),
                    "zstd" => {
                        match zstd::bulk::decompress(&data, header.uncompressed_size as usize) {
                            Ok(d) => d,
                            Err(e) => {
                                self.out.skipped_chunks.push(format!("zstd: {e}"));
                                return Ok(());
                            }
                        }
                    }
                    other => {
                        self.out
                            .skipped_chunks
                            .push(format!("unsupported chunk compression {other:?}"));
                        return Ok(());
                    }
                };
                if uncompressed.len() as u64 != header.uncompressed_size {
                    self.out.skipped_chunks.push(format!(
                        "chunk decompressed to {} bytes, header says {}",
                        uncompressed.len(),
                        header.uncompressed_size
                    ));
                    return Ok(());
                }
                if header.uncompressed_crc != 0
                    && crc32fast::hash(&uncompressed) != header.uncompressed_crc
                {
                    self.out.skipped_chunks.push("chunk CRC mismatch".into());
                    return Ok(());
                }
                // Only the records before one whose length prefixes overrun it.
                let intact = match crate::length_guard::first_overlong(&uncompressed) {
                    Some((at, problem)) => {
                        self.out.skipped_chunks.push(problem);
                        &uncompressed[..at]
                    }
                    None => &uncompressed[..],
                };
                for inner in LinearReader::sans_magic(intact) {
                    match inner {
                        Ok(r) => self.record(r, true)?,
                        Err(e) => {
                            // Messages before the damage were delivered; the rest of this
                            // chunk is lost.
                            self.out.skipped_chunks.push(e.to_string());
                            break;
                        }
                    }
                }
            }
            Record::Metadata(m) if !in_chunk => {
                (self.visit)(Event::Metadata(&m))?;
            }
            Record::Attachment { header, data, .. } if !in_chunk => {
                (self.visit)(Event::Attachment {
                    name: &header.name,
                    media_type: &header.media_type,
                    log_time: header.log_time,
                    data: &data,
                })?;
            }
            Record::DataEnd(_) => self.out.data_end = true,
            Record::Footer(_) => self.out.footer = true,
            _ => {}
        }
        Ok(())
    }
}

/// Scans `bytes` (the contents of `path`) from start to end, calling `visit` for every
/// message, metadata record and attachment. Stops quietly at a torn tail (reported in
/// `stopped_early`); fails with a typed error on a file that is not a ROS 2 MCAP.
pub fn scan_bytes(
    path: &Path,
    bytes: &[u8],
    visit: &mut dyn FnMut(Event<'_>) -> Result<(), RecordingError>,
) -> Result<ScanOutcome, RecordingError> {
    if bytes.len() < mcap::MAGIC.len() || !bytes.starts_with(mcap::MAGIC) {
        return Err(RecordingError::NotMcap {
            path: path.to_path_buf(),
        });
    }
    // The mcap crate is not supposed to panic on bad input; this guard turns a bug there
    // into a typed error instead of taking the caller down.
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let mut scanner = Scanner {
            path: path.to_path_buf(),
            schemas: BTreeMap::new(),
            out: ScanOutcome::default(),
            visit,
        };
        // Records from the first one whose length prefixes overrun it are not handed to the
        // parser (it would reserve what they claim): a damaged tail, like a torn one.
        let overlong = crate::length_guard::first_overlong(&bytes[mcap::MAGIC.len()..]);
        let intact = match &overlong {
            Some((0, problem)) => {
                return Err(RecordingError::Corrupt {
                    path: path.to_path_buf(),
                    offset: mcap::MAGIC.len() as u64,
                    detail: format!("header record: {problem}"),
                })
            }
            Some((at, _)) => &bytes[..mcap::MAGIC.len() + at],
            None => bytes,
        };
        let reader = LinearReader::new(intact).map_err(|e| RecordingError::Corrupt {
            path: path.to_path_buf(),
            offset: 0,
            detail: e.to_string(),
        })?;
        let mut first = true;
        let mut records = 0u64;
        for record in reader {
            match record {
                Ok(r) => {
                    if first && !matches!(r, Record::Header(_)) {
                        return Err(RecordingError::Corrupt {
                            path: path.to_path_buf(),
                            offset: 8,
                            detail: "first record is not a header".into(),
                        });
                    }
                    first = false;
                    records += 1;
                    scanner.record(r, false)?;
                }
                Err(e) => {
                    if records == 0 {
                        return Err(RecordingError::Truncated {
                            path: path.to_path_buf(),
                            detail: e.to_string(),
                        });
                    }
                    scanner.out.stopped_early = Some(format!("after {records} records: {e}"));
                    break;
                }
            }
        }
        if records == 0 {
            return Err(RecordingError::Truncated {
                path: path.to_path_buf(),
                detail: "no header record".into(),
            });
        }
        if let Some((at, problem)) = overlong {
            scanner.out.stopped_early = Some(format!(
                "after {records} records, at byte {}: {problem}",
                mcap::MAGIC.len() + at
            ));
        }
        Ok(scanner.out)
    }));
    match result {
        Ok(r) => r,
        Err(_) => Err(RecordingError::Corrupt {
            path: path.to_path_buf(),
            offset: 0,
            detail: "MCAP parser failed on malformed input".into(),
        }),
    }
}

/// Reads `path` and scans it (see [`scan_bytes`]).
pub fn scan(
    path: &Path,
    visit: &mut dyn FnMut(Event<'_>) -> Result<(), RecordingError>,
) -> Result<ScanOutcome, RecordingError> {
    let bytes = load(path)?;
    scan_bytes(path, &bytes, visit)
}

/// Checks that `channel` carries exactly our definition of `T` (name and schema text), so
/// its CDR payloads can be decoded positionally.
pub fn check_schema<T: RosMessage>(
    path: &Path,
    channel: &ChannelInfo,
) -> Result<(), RecordingError> {
    let expected_name = ros::type_name::<T>();
    if channel.schema_name != expected_name || channel.schema_text != ros::schema_text::<T>() {
        return Err(RecordingError::UnknownSchema {
            path: path.to_path_buf(),
            topic: channel.topic.clone(),
            schema: if channel.schema_name == expected_name {
                format!(
                    "{} (definition differs from this build's)",
                    channel.schema_name
                )
            } else {
                channel.schema_name.clone()
            },
            encoding: channel.schema_encoding.clone(),
        });
    }
    Ok(())
}

/// Decodes a message of a checked channel.
pub fn decode<T: RosMessage>(
    path: &Path,
    channel: &ChannelInfo,
    header: &MessageHeader,
    data: &[u8],
) -> Result<T, RecordingError> {
    ros::from_cdr::<T>(data).map_err(|e| RecordingError::Decode {
        path: path.to_path_buf(),
        topic: channel.topic.clone(),
        sequence: header.sequence as u64,
        schema: channel.schema_name.clone(),
        detail: e.to_string(),
    })
}

/// A stretch of a topic with no messages.
#[derive(Debug, Clone, Serialize)]
pub struct Gap {
    /// Start of the gap, s after the recording's first message.
    pub at_s: f64,
    pub length_s: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct TopicInfo {
    pub topic: String,
    pub type_name: String,
    pub count: u64,
    pub first_ns: u64,
    pub last_ns: u64,
    /// Mean rate over the topic's own span, Hz.
    pub rate_hz: f64,
    /// Intervals longer than max(5 × median interval, 50 ms).
    pub gaps: Vec<Gap>,
    /// Lossless channels: messages missing by their own sequence numbers (dropped
    /// upstream of the file).
    pub sequence_missing: Option<u64>,
    /// Lossless channels: messages whose sequence number was already recorded (the same
    /// sample twice, e.g. in two parts of a restarted recorder).
    pub sequence_repeated: Option<u64>,
}

/// Summary of a recording (`arthrosim recordings info`).
#[derive(Debug, Clone, Serialize)]
pub struct RecordingInfo {
    pub path: PathBuf,
    pub bytes: u64,
    pub profile: String,
    pub library: String,
    /// Closed cleanly (data end, summary and footer present).
    pub complete: bool,
    pub stopped_early: Option<String>,
    pub skipped_chunks: usize,
    pub messages: u64,
    pub start_ns: u64,
    pub end_ns: u64,
    pub duration_s: f64,
    pub topics: Vec<TopicInfo>,
    pub metadata: Vec<String>,
    pub attachments: Vec<String>,
    /// The `arthrosim_session` metadata record (session name, launch path, source).
    pub session: BTreeMap<String, String>,
    /// The files read, in order (`session.mcap`, then `session.1.mcap`, … written by a
    /// restarted recorder).
    pub parts: Vec<PathBuf>,
}

struct TopicAcc {
    times: Vec<u64>,
    /// Newest sequence number per publisher instance.
    newest: BTreeMap<u64, u64>,
    /// Instance of the previous message (a new instance restarts the count).
    last_instance: Option<u64>,
    missing: u64,
    repeated: u64,
    lossless: bool,
}

/// Topics, counts, rates, duration, gaps of the recording at `path`: all of its parts in
/// order (a session folder, or any part: see [`session_parts`]).
pub fn info(path: &Path) -> Result<RecordingInfo, RecordingError> {
    // Per topic (channel ids differ between parts), in order of first appearance.
    let mut acc: BTreeMap<String, TopicAcc> = BTreeMap::new();
    let mut metadata = Vec::new();
    let mut attachments = Vec::new();
    let mut session = BTreeMap::new();
    let mut total_bytes = 0u64;
    let mut parts = Vec::new();
    let mut outcomes: Vec<(PathBuf, ScanOutcome)> = Vec::new();
    for part in session_parts(path)? {
        let bytes = load(&part)?;
        total_bytes += bytes.len() as u64;
        let mut checked: BTreeMap<u16, bool> = BTreeMap::new();
        let path = part.as_path();
        let outcome = scan_bytes(path, &bytes, &mut |event| {
            match event {
                Event::Message {
                    channel,
                    header,
                    data,
                } => {
                    let lossless = *checked.entry(channel.id).or_insert_with(|| {
                        (channel.topic == TOPIC_CONTACT_STEP
                            && check_schema::<ContactStep>(path, channel).is_ok())
                            || (channel.topic == TOPIC_DEVICE_TICK
                                && check_schema::<DeviceTick>(path, channel).is_ok())
                    });
                    let a = acc
                        .entry(channel.topic.clone())
                        .or_insert_with(|| TopicAcc {
                            times: Vec::new(),
                            newest: BTreeMap::new(),
                            last_instance: None,
                            missing: 0,
                            repeated: 0,
                            lossless,
                        });
                    a.times.push(header.log_time);
                    if lossless {
                        // Only the leading fields are needed: instance id and sequence.
                        let ids = if channel.topic == TOPIC_CONTACT_STEP {
                            decode::<ContactStep>(path, channel, &header, data)
                                .map(|m| (m.instance_id, m.sequence))
                        } else {
                            decode::<DeviceTick>(path, channel, &header, data)
                                .map(|m| (m.instance_id, m.sequence))
                        };
                        let (instance, seq) = ids?;
                        match a.newest.get(&instance).copied() {
                            Some(newest) if seq <= newest => a.repeated += 1,
                            Some(newest) => {
                                // Gaps within one instance's run; a publisher that came back
                                // (another instance in between) restarts the count.
                                if a.last_instance == Some(instance) {
                                    a.missing += seq - newest - 1;
                                }
                                a.newest.insert(instance, seq);
                            }
                            None => {
                                a.newest.insert(instance, seq);
                            }
                        }
                        a.last_instance = Some(instance);
                    }
                }
                Event::Metadata(m) => {
                    if m.name == SESSION_METADATA && session.is_empty() {
                        session = m.metadata.clone();
                    }
                    metadata.push(m.name.clone());
                }
                Event::Attachment { name, .. } => attachments.push(name.to_string()),
            }
            Ok(())
        })?;
        parts.push(part.clone());
        outcomes.push((part, outcome));
    }
    metadata.dedup();
    attachments.dedup();
    let start_ns = acc
        .values()
        .filter_map(|a| a.times.iter().min().copied())
        .min()
        .unwrap_or(0);
    let end_ns = acc
        .values()
        .filter_map(|a| a.times.iter().max().copied())
        .max()
        .unwrap_or(0);
    let mut topics = Vec::new();
    let mut channels: Vec<&ChannelInfo> = Vec::new();
    for (_, o) in &outcomes {
        for c in o.channels.values() {
            if !channels.iter().any(|k| k.topic == c.topic) {
                channels.push(c);
            }
        }
    }
    for channel in channels {
        let (count, first_ns, last_ns, rate_hz, gaps, missing, repeated) =
            match acc.get_mut(&channel.topic) {
                Some(a) if !a.times.is_empty() => {
                    a.times.sort_unstable();
                    let first = a.times[0];
                    let last = *a.times.last().unwrap_or(&first);
                    let n = a.times.len() as u64;
                    let span = (last - first) as f64 * 1e-9;
                    let rate = if n > 1 && span > 0.0 {
                        (n - 1) as f64 / span
                    } else {
                        0.0
                    };
                    let mut intervals: Vec<u64> = a.times.windows(2).map(|w| w[1] - w[0]).collect();
                    let gaps = if intervals.len() >= 2 {
                        let mut sorted = intervals.clone();
                        sorted.sort_unstable();
                        let median = sorted[sorted.len() / 2];
                        let threshold = (median.saturating_mul(5)).max(50_000_000);
                        a.times
                            .windows(2)
                            .filter(|w| w[1] - w[0] > threshold)
                            .map(|w| Gap {
                                at_s: (w[0] - start_ns) as f64 * 1e-9,
                                length_s: (w[1] - w[0]) as f64 * 1e-9,
                            })
                            .collect()
                    } else {
                        Vec::new()
                    };
                    intervals.clear();
                    (
                        n,
                        first,
                        last,
                        rate,
                        gaps,
                        a.lossless.then_some(a.missing),
                        a.lossless.then_some(a.repeated),
                    )
                }
                _ => (0, 0, 0, 0.0, Vec::new(), None, None),
            };
        topics.push(TopicInfo {
            topic: channel.topic.clone(),
            type_name: channel.schema_name.clone(),
            count,
            first_ns,
            last_ns,
            rate_hz,
            gaps,
            sequence_missing: missing,
            sequence_repeated: repeated,
        });
    }
    let first = &outcomes[0].1;
    let multi = outcomes.len() > 1;
    let stopped_early = outcomes.iter().find_map(|(p, o)| {
        o.stopped_early.as_ref().map(|why| {
            if multi {
                format!("{}: {why}", p.display())
            } else {
                why.clone()
            }
        })
    });
    Ok(RecordingInfo {
        path: parts[0].clone(),
        bytes: total_bytes,
        profile: first.profile.clone(),
        library: first.library.clone(),
        complete: outcomes
            .iter()
            .all(|(_, o)| o.data_end && o.footer && o.stopped_early.is_none()),
        stopped_early,
        skipped_chunks: outcomes.iter().map(|(_, o)| o.skipped_chunks.len()).sum(),
        messages: outcomes.iter().map(|(_, o)| o.messages).sum(),
        start_ns,
        end_ns,
        duration_s: end_ns.saturating_sub(start_ns) as f64 * 1e-9,
        topics,
        metadata,
        attachments,
        session,
        parts,
    })
}

impl std::fmt::Display for RecordingInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "file:      {} ({} bytes)",
            self.path.display(),
            self.bytes
        )?;
        if self.parts.len() > 1 {
            let names: Vec<String> = self.parts.iter().map(|p| p.display().to_string()).collect();
            writeln!(f, "parts:     {} ({})", self.parts.len(), names.join(", "))?;
        }
        writeln!(f, "profile:   {} ({})", self.profile, self.library)?;
        if let Some(s) = self.session.get("session") {
            writeln!(
                f,
                "session:   {s} (source: {})",
                self.session
                    .get("source")
                    .map(String::as_str)
                    .unwrap_or("?")
            )?;
        }
        let state = if self.complete {
            "complete".to_string()
        } else {
            format!(
                "INCOMPLETE ({}); `arthrosim recordings repair` rewrites it with summary and index",
                self.stopped_early.as_deref().unwrap_or("no summary")
            )
        };
        writeln!(f, "state:     {state}")?;
        if self.skipped_chunks > 0 {
            writeln!(f, "skipped:   {} damaged chunk(s)", self.skipped_chunks)?;
        }
        writeln!(
            f,
            "duration:  {:.3} s, {} messages",
            self.duration_s, self.messages
        )?;
        writeln!(f, "topics:")?;
        for t in &self.topics {
            write!(
                f,
                "  {:<36} {:<34} {:>9} msgs {:>9.2} Hz",
                t.topic, t.type_name, t.count, t.rate_hz
            )?;
            if let Some(m) = t.sequence_missing {
                write!(f, "  missing {m}")?;
            }
            if let Some(r) = t.sequence_repeated.filter(|&r| r > 0) {
                write!(f, "  repeated {r}")?;
            }
            if !t.gaps.is_empty() {
                let longest = t.gaps.iter().map(|g| g.length_s).fold(0.0, f64::max);
                write!(f, "  {} gap(s), longest {:.3} s", t.gaps.len(), longest)?;
            }
            writeln!(f)?;
        }
        if !self.attachments.is_empty() {
            writeln!(f, "attachments: {}", self.attachments.join(", "))?;
        }
        if !self.metadata.is_empty() {
            writeln!(f, "metadata:    {}", self.metadata.join(", "))?;
        }
        Ok(())
    }
}

/// Splits `name.mcap` / `name.N.mcap` into (`name`, N) (0 for the first part).
fn part_of(file_name: &str) -> Option<(&str, u32)> {
    let stem = file_name.strip_suffix(".mcap")?;
    if let Some((base, n)) = stem.rsplit_once('.') {
        if !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) && n.len() <= 9 {
            return Some((base, n.parse().ok()?));
        }
    }
    Some((stem, 0))
}

/// The file a recorder (re)started in `dir` writes for `file_name` (`session.mcap`): the
/// name itself when free, else the first free `session.N.mcap` after the highest existing
/// part, so a restarted recorder never reopens (and never truncates) an earlier part.
pub fn next_part_path(dir: &Path, file_name: &str) -> PathBuf {
    let Some((base, _)) = part_of(file_name) else {
        return dir.join(file_name);
    };
    let first = dir.join(format!("{base}.mcap"));
    if !first.exists() {
        return first;
    }
    let mut highest = 0;
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            if let Some((b, n)) = e.file_name().to_str().and_then(part_of) {
                if b == base {
                    highest = highest.max(n);
                }
            }
        }
    }
    dir.join(format!("{base}.{}.mcap", highest + 1))
}

/// The parts of a recording, in order: for `…/session.mcap` (or any of its parts
/// `session.N.mcap`) every existing `session.mcap`, `session.1.mcap`, … in that folder;
/// for a session folder, the parts of its `session.mcap` (or of its only recording).
pub fn session_parts(path: &Path) -> Result<Vec<PathBuf>, RecordingError> {
    let (dir, base) = if path.is_dir() {
        let mut bases: Vec<String> = std::fs::read_dir(path)
            .map_err(|e| RecordingError::io(path, e))?
            .flatten()
            .filter_map(|e| {
                e.file_name()
                    .to_str()
                    .and_then(part_of)
                    .map(|(b, _)| b.to_string())
            })
            .collect();
        bases.sort();
        bases.dedup();
        let base = if bases.iter().any(|b| b == "session") {
            "session".to_string()
        } else if bases.len() == 1 {
            bases.remove(0)
        } else if bases.is_empty() {
            return Err(RecordingError::io(
                path,
                std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "no .mcap recording in this folder",
                ),
            ));
        } else {
            return Err(RecordingError::io(
                path,
                std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    format!(
                        "several recordings in this folder ({}); name one",
                        bases.join(", ")
                    ),
                ),
            ));
        };
        (path.to_path_buf(), base)
    } else {
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        match part_of(name) {
            Some((base, _)) => (
                path.parent().unwrap_or(Path::new("")).to_path_buf(),
                base.to_string(),
            ),
            // Not named like a part: just this file.
            None => return Ok(vec![path.to_path_buf()]),
        }
    };
    let mut parts: Vec<(u32, PathBuf)> = Vec::new();
    let listing = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir.as_path()
    };
    for e in std::fs::read_dir(listing)
        .map_err(|e| RecordingError::io(listing, e))?
        .flatten()
    {
        if let Some((b, n)) = e.file_name().to_str().and_then(part_of) {
            if b == base && e.path().is_file() {
                parts.push((n, dir.join(e.file_name())));
            }
        }
    }
    parts.sort();
    if parts.is_empty() {
        // Let the caller's read name the missing file.
        return Ok(vec![path.to_path_buf()]);
    }
    Ok(parts.into_iter().map(|(_, p)| p).collect())
}

/// Scans every part of the recording at `path` in order (see [`session_parts`]); the
/// visitor also gets the part being read. Returns each part's outcome.
pub fn scan_parts(
    path: &Path,
    visit: &mut dyn FnMut(&Path, Event<'_>) -> Result<(), RecordingError>,
) -> Result<Vec<(PathBuf, ScanOutcome)>, RecordingError> {
    let mut outcomes = Vec::new();
    for part in session_parts(path)? {
        let bytes = load(&part)?;
        let outcome = scan_bytes(&part, &bytes, &mut |e| visit(&part, e))?;
        outcomes.push((part, outcome));
    }
    Ok(outcomes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every restart takes the part after the highest one (never an earlier name, so never a
    /// truncation), and the set is read in numeric order (`session.10.mcap` after
    /// `session.2.mcap`, not between `session.1.mcap` and `session.2.mcap`). The end-to-end
    /// test (`tests/tests/session_safety.rs`) restarts the recorder once; this covers more.
    #[test]
    fn restarted_parts_follow_the_highest_and_are_read_in_numeric_order() {
        let dir = std::env::temp_dir().join(format!("arthrosim-parts-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let touch = |p: &PathBuf| std::fs::write(p, b"x").unwrap();
        assert_eq!(
            next_part_path(&dir, "session.mcap"),
            dir.join("session.mcap")
        );
        touch(&dir.join("session.mcap"));
        for n in 1..=11 {
            let next = next_part_path(&dir, "session.mcap");
            assert_eq!(next, dir.join(format!("session.{n}.mcap")));
            touch(&next);
        }
        // A missing part in the middle (deleted by hand) is not reused.
        std::fs::remove_file(dir.join("session.5.mcap")).unwrap();
        assert_eq!(
            next_part_path(&dir, "session.mcap"),
            dir.join("session.12.mcap")
        );
        // Other files in the folder are not parts.
        touch(&dir.join("session.repaired.mcap"));
        touch(&dir.join("contact_force.csv"));
        let expected: Vec<PathBuf> = std::iter::once(dir.join("session.mcap"))
            .chain(
                (1..=11)
                    .filter(|&n| n != 5)
                    .map(|n| dir.join(format!("session.{n}.mcap"))),
            )
            .collect();
        for from in [
            dir.clone(),
            dir.join("session.mcap"),
            dir.join("session.10.mcap"),
        ] {
            assert_eq!(
                session_parts(&from).unwrap(),
                expected,
                "from {}",
                from.display()
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

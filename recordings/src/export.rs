//! CSV exports: the study's force/pose CSV (whole session, per region, per probing) and the
//! device trajectory in the haptic node's replay format.

use crate::channels::*;
use crate::error::RecordingError;
use crate::read::{check_schema, decode, scan_parts, ChannelInfo, Event};
use mcap::records::MessageHeader;
use msgs::protocol::Region;
use serde::Serialize;
use session_metrics::{Annotations, SessionRecord, SessionSummary};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Header of the study CSV.
pub const STUDY_CSV_HEADER: &str = "time_s,force_x_n,force_y_n,force_z_n,contact,normal_force_n,probe_px_m,probe_py_m,probe_pz_m,probe_qx,probe_qy,probe_qz,probe_qw,region,probing,phase";
/// Header of the haptic node's replay CSV.
pub const REPLAY_CSV_HEADER: &str = "t_s,px_m,py_m,pz_m,qx,qy,qz,qw";

/// One physics step as the study CSV has it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StudyRow {
    pub time_s: f64,
    pub force: [f64; 3],
    /// In contact, as `session_metrics::ContactSample::in_contact` defines it.
    pub contact: bool,
    /// F_n = −f·n (negative in compression), 0 out of contact.
    pub normal_force_n: f64,
    pub probe: msgs::Pose,
    pub region: u32,
    pub probing: u32,
    pub phase: u32,
}

/// One written file and its row count.
#[derive(Debug, Clone, Serialize)]
pub struct ExportedFile {
    pub path: PathBuf,
    pub rows: usize,
}

/// What `export_csv` wrote.
#[derive(Debug, Clone, Serialize)]
pub struct ExportSummary {
    pub files: Vec<ExportedFile>,
    /// Steps whose device annotations were not found (no matching device tick).
    pub unannotated_steps: usize,
}

/// The lossless channels of a recording as they are scanned: every ContactStep and DeviceTick
/// in file order, each channel's schema checked once.
#[derive(Default)]
pub struct LosslessChannels {
    checked: std::collections::BTreeSet<u16>,
    pub steps: Vec<ContactStep>,
    pub ticks: Vec<DeviceTick>,
}

impl LosslessChannels {
    /// Takes one scanned message (other topics are ignored).
    pub fn push(
        &mut self,
        path: &Path,
        channel: &ChannelInfo,
        header: &MessageHeader,
        data: &[u8],
    ) -> Result<(), RecordingError> {
        if channel.topic == TOPIC_CONTACT_STEP {
            if self.checked.insert(channel.id) {
                check_schema::<ContactStep>(path, channel)?;
            }
            self.steps
                .push(decode::<ContactStep>(path, channel, header, data)?);
        } else if channel.topic == TOPIC_DEVICE_TICK {
            if self.checked.insert(channel.id) {
                check_schema::<DeviceTick>(path, channel)?;
            }
            self.ticks
                .push(decode::<DeviceTick>(path, channel, header, data)?);
        }
        Ok(())
    }
}

/// Reads the lossless channels: every ContactStep and DeviceTick, in file order, over all
/// parts of the recording (`session.mcap`, `session.1.mcap`, …; see
/// [`crate::read::session_parts`]).
pub fn read_lossless(path: &Path) -> Result<(Vec<ContactStep>, Vec<DeviceTick>), RecordingError> {
    let mut lossless = LosslessChannels::default();
    scan_parts(path, &mut |part, event| {
        if let Event::Message {
            channel,
            header,
            data,
        } = event
        {
            lossless.push(part, channel, &header, data)?;
        }
        Ok(())
    })?;
    Ok((lossless.steps, lossless.ticks))
}

/// The annotations of a recording's device ticks.
fn annotations(ticks: &[DeviceTick]) -> Annotations {
    let mut a = Annotations::default();
    for t in ticks {
        a.push(t.sequence, t.region, t.probing_index, t.phase);
    }
    a
}

/// Study rows of a recording: one per physics step, annotated with the protocol state of
/// the device tick each step consumed (`session_metrics::matching`).
pub fn study_rows(path: &Path) -> Result<(Vec<StudyRow>, usize), RecordingError> {
    let (steps, ticks) = read_lossless(path)?;
    if steps.is_empty() {
        return Err(RecordingError::MissingTopic {
            path: path.to_path_buf(),
            topic: TOPIC_CONTACT_STEP.into(),
            why: "the study CSV is built from the physics steps".into(),
        });
    }
    let annotations = annotations(&ticks);
    let mut unannotated = 0;
    let rows = steps
        .iter()
        .map(|s| {
            let a = annotations.of_step(s.device_sequence_used);
            if a.is_none() && s.device_sequence_used != 0 {
                unannotated += 1;
            }
            let a = a.unwrap_or_default();
            let sample = s.sample();
            let contact = sample.in_contact();
            StudyRow {
                time_s: s.sim_time,
                force: sample.contact_force,
                contact,
                normal_force_n: if contact { sample.normal_force() } else { 0.0 },
                probe: (&s.probe_pose).into(),
                region: a.region,
                probing: a.probing_index,
                phase: a.phase,
            }
        })
        .collect();
    Ok((rows, unannotated))
}

/// The study's per-region summary of a recording, from its lossless channels: the same
/// function the launcher applies to the live streams.
pub fn session_summary(path: &Path) -> Result<SessionSummary, RecordingError> {
    let (steps, ticks) = read_lossless(path)?;
    let mut record = SessionRecord::default();
    record.contacts = steps.iter().map(ContactStep::sample).collect();
    for t in &ticks {
        record.push_device(
            t.instance_id,
            t.sequence,
            t.publish_ns,
            t.region,
            t.probing_index,
            t.phase,
        );
    }
    Ok(session_metrics::summarize(&record))
}

fn write_rows<'a>(
    path: &Path,
    rows: impl Iterator<Item = &'a StudyRow>,
) -> Result<usize, RecordingError> {
    let file = std::fs::File::create(path).map_err(|e| RecordingError::io(path, e))?;
    let mut w = std::io::BufWriter::new(file);
    let io = |e| RecordingError::io(path, e);
    writeln!(w, "{STUDY_CSV_HEADER}").map_err(io)?;
    let mut n = 0;
    for r in rows {
        let p = &r.probe.position;
        let q = &r.probe.orientation;
        // `{}` on f64 prints the shortest text that parses back to the same bits.
        writeln!(
            w,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.time_s,
            r.force[0],
            r.force[1],
            r.force[2],
            r.contact as u8,
            r.normal_force_n,
            p[0],
            p[1],
            p[2],
            q[0],
            q[1],
            q[2],
            q[3],
            r.region,
            r.probing,
            r.phase
        )
        .map_err(io)?;
        n += 1;
    }
    w.flush().map_err(io)?;
    Ok(n)
}

/// Writes the study CSV of `path` into `dir`: `session.csv` (every physics step),
/// `region_<name>.csv` per region present, `probing_<NNN>_<region>.csv` per probing.
pub fn export_csv(path: &Path, dir: &Path) -> Result<ExportSummary, RecordingError> {
    let (rows, unannotated) = study_rows(path)?;
    std::fs::create_dir_all(dir).map_err(|e| RecordingError::io(dir, e))?;
    let mut files = Vec::new();
    let all = dir.join("session.csv");
    let n = write_rows(&all, rows.iter())?;
    files.push(ExportedFile { path: all, rows: n });
    for code in 1..=3u32 {
        if rows.iter().any(|r| r.region == code) {
            let p = dir.join(format!("region_{}.csv", Region::name_of_code(code)));
            let n = write_rows(&p, rows.iter().filter(|r| r.region == code))?;
            files.push(ExportedFile { path: p, rows: n });
        }
    }
    let mut probings: Vec<(u32, u32)> = rows
        .iter()
        .filter(|r| r.probing > 0)
        .map(|r| (r.probing, r.region))
        .collect();
    probings.sort_unstable();
    probings.dedup_by_key(|p| p.0);
    for (index, region) in probings {
        let p = dir.join(format!(
            "probing_{index:03}_{}.csv",
            Region::name_of_code(region)
        ));
        let n = write_rows(&p, rows.iter().filter(|r| r.probing == index))?;
        files.push(ExportedFile { path: p, rows: n });
    }
    Ok(ExportSummary {
        files,
        unannotated_steps: unannotated,
    })
}

/// Writes the recorded device trajectory (every haptic tick's proxy pose) as the haptic
/// node's replay CSV (`t_s,px_m,py_m,pz_m,qx,qy,qz,qw`, t from the first tick). Returns the
/// number of rows.
pub fn export_replay_csv(path: &Path, out: &Path) -> Result<usize, RecordingError> {
    let (_, mut ticks) = read_lossless(path)?;
    if ticks.is_empty() {
        return Err(RecordingError::MissingTopic {
            path: path.to_path_buf(),
            topic: TOPIC_DEVICE_TICK.into(),
            why: "the device trajectory comes from the haptic ticks".into(),
        });
    }
    // Time from the header stamps (wall clock of each tick), in tick order.
    ticks.sort_by_key(|t| (t.header.stamp.to_nanos(), t.sequence));
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| RecordingError::io(dir, e))?;
    }
    let file = std::fs::File::create(out).map_err(|e| RecordingError::io(out, e))?;
    let mut w = std::io::BufWriter::new(file);
    let io = |e| RecordingError::io(out, e);
    writeln!(w, "{REPLAY_CSV_HEADER}").map_err(io)?;
    let t0 = ticks[0].header.stamp.to_nanos();
    for t in &ticks {
        let p = &t.proxy_pose;
        writeln!(
            w,
            "{},{},{},{},{},{},{},{}",
            (t.header.stamp.to_nanos() - t0) as f64 * 1e-9,
            p.position.x,
            p.position.y,
            p.position.z,
            p.orientation.x,
            p.orientation.y,
            p.orientation.z,
            p.orientation.w
        )
        .map_err(io)?;
    }
    w.flush().map_err(io)?;
    Ok(ticks.len())
}

//! Fuzz-style: truncated, corrupted, random, wrong-profile, unknown-schema and non-MCAP
//! files given to `info`, `export_csv` and `repair` give typed errors (or partial results),
//! never a panic.

mod common;

use common::*;
use launch_config::RecordingConfig;
use msgs::haptic_to_physics::DeviceState;
use msgs::physics_to_haptic::ContactFrame;
use recordings::channels::*;
use recordings::{RecordingError, SessionInfo, SessionWriter};
use std::collections::BTreeMap;
use std::path::Path;

fn small_session(path: &Path) -> Vec<u8> {
    let config = RecordingConfig {
        flush_interval_s: 0.05,
        ..Default::default()
    };
    let mut w = SessionWriter::create(path, &config, &SessionInfo::default()).unwrap();
    let mut d = boxed_zeroed::<DeviceState>();
    let mut f = boxed_zeroed::<ContactFrame>();
    for seq in 1..=200u64 {
        fill_device(&mut d, seq, 1);
        let log = 1_000_000_000 + seq * 1_000_000;
        w.write_device_state(&d, log).unwrap();
        if seq % 10 == 0 {
            fill_frame(&mut f, seq / 10, 2, seq);
            w.write_contact_frame(&f, log).unwrap();
        }
        w.maybe_flush(log).unwrap();
    }
    w.finish(BTreeMap::new()).unwrap();
    std::fs::read(path).unwrap()
}

struct XorShift(u64);
impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

/// Every entry point on `path`: must return (Ok or a typed error), never panic.
fn exercise(path: &Path, out: &Path) -> Option<RecordingError> {
    let a = recordings::info(path).err();
    let _ = recordings::export_csv(path, &out.join("csv"));
    let _ = recordings::export_replay_csv(path, &out.join("traj.csv"));
    let _ = recordings::repair(path, &out.join("repaired.mcap"));
    a
}

#[test]
fn truncated_files_read_up_to_the_cut_or_fail_typed() {
    let dir = test_dir("bad-truncated");
    let good = small_session(&dir.join("good.mcap"));
    let path = dir.join("cut.mcap");
    let full = recordings::info(&dir.join("good.mcap")).unwrap();
    let total_ticks = full
        .topics
        .iter()
        .find(|t| t.topic == TOPIC_DEVICE_TICK)
        .unwrap()
        .count;
    assert_eq!(total_ticks, 200);
    let mut last_ticks = 0;
    let step = (good.len() / 1500).max(1);
    for cut in (0..good.len()).step_by(step) {
        std::fs::write(&path, &good[..cut]).unwrap();
        match recordings::info(&path) {
            Ok(info) => {
                assert!(!info.complete || cut == good.len());
                let ticks = info
                    .topics
                    .iter()
                    .find(|t| t.topic == TOPIC_DEVICE_TICK)
                    .map_or(0, |t| t.count);
                assert!(
                    ticks >= last_ticks,
                    "a longer prefix never reads fewer messages"
                );
                last_ticks = ticks;
            }
            Err(RecordingError::NotMcap { .. }) => assert!(cut < 8),
            Err(RecordingError::Truncated { .. }) => assert!(cut < 200, "cut {cut}"),
            Err(e) => panic!("cut {cut}: unexpected {e}"),
        }
        if cut % (step * 50) == 0 {
            exercise(&path, &dir);
        }
    }
    assert!(
        last_ticks > 150,
        "most of the file is readable from a prefix: {last_ticks}"
    );
}

#[test]
fn corrupted_and_random_files_never_panic() {
    let dir = test_dir("bad-corrupt");
    let good = small_session(&dir.join("good.mcap"));
    let path = dir.join("bad.mcap");
    let mut rng = XorShift(0x9E37_79B9_7F4A_7C15);
    for round in 0..400 {
        let mut bytes = good.clone();
        let flips = 1 + (rng.next() % 8) as usize;
        for _ in 0..flips {
            let i = (rng.next() as usize) % bytes.len();
            bytes[i] ^= 1 << (rng.next() % 8);
        }
        if round % 4 == 0 {
            // Also overwrite a run with garbage (length fields, chunk headers).
            let i = (rng.next() as usize) % bytes.len();
            let n = ((rng.next() % 64) as usize).min(bytes.len() - i);
            for b in &mut bytes[i..i + n] {
                *b = rng.next() as u8;
            }
        }
        std::fs::write(&path, &bytes).unwrap();
        if round % 20 == 0 {
            exercise(&path, &dir);
        } else {
            let _ = recordings::info(&path);
        }
    }
    for len in [0usize, 1, 7, 8, 9, 100, 5000] {
        let mut bytes: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
        std::fs::write(&path, &bytes).unwrap();
        assert!(matches!(
            exercise(&path, &dir),
            Some(RecordingError::NotMcap { .. })
        ));
        // Random bytes behind a valid magic.
        if len >= 8 {
            bytes[..8].copy_from_slice(mcap::MAGIC);
            std::fs::write(&path, &bytes).unwrap();
            assert!(
                exercise(&path, &dir).is_some(),
                "random body after magic is an error"
            );
        }
    }
}

#[test]
fn not_mcap_missing_file_wrong_profile_and_unknown_schema_are_typed_errors() {
    let dir = test_dir("bad-kinds");
    let text = dir.join("notes.txt");
    std::fs::write(&text, "time_s,force\n0,1\n").unwrap();
    let e = recordings::info(&text).unwrap_err();
    assert!(matches!(e, RecordingError::NotMcap { .. }), "{e}");
    assert!(
        e.to_string().contains("notes.txt"),
        "error names the file: {e}"
    );
    assert!(matches!(
        recordings::export_csv(&text, &dir).unwrap_err(),
        RecordingError::NotMcap { .. }
    ));

    let missing = dir.join("missing.mcap");
    assert!(matches!(
        recordings::info(&missing).unwrap_err(),
        RecordingError::Io { .. }
    ));

    // A valid MCAP with another profile.
    let other = dir.join("other.mcap");
    {
        let mut w = mcap::WriteOptions::new()
            .profile("ros1")
            .create(std::io::BufWriter::new(
                std::fs::File::create(&other).unwrap(),
            ))
            .unwrap();
        w.finish().unwrap();
    }
    let e = recordings::info(&other).unwrap_err();
    assert!(
        matches!(&e, RecordingError::WrongProfile { found, .. } if found == "ros1"),
        "{e}"
    );

    // ros2 profile, but a channel with a JSON schema.
    let json = dir.join("json.mcap");
    {
        let mut w = mcap::WriteOptions::new()
            .profile("ros2")
            .create(std::io::BufWriter::new(
                std::fs::File::create(&json).unwrap(),
            ))
            .unwrap();
        let s = w.add_schema("Thing", "jsonschema", b"{}").unwrap();
        let c = w
            .add_channel(s, "/thing", "json", &BTreeMap::new())
            .unwrap();
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: c,
                sequence: 1,
                log_time: 1,
                publish_time: 1,
            },
            b"{}",
        )
        .unwrap();
        w.finish().unwrap();
    }
    let e = recordings::info(&json).unwrap_err();
    assert!(
        matches!(&e, RecordingError::UnknownSchema { topic, .. } if topic == "/thing"),
        "{e}"
    );

    // Our topic with a definition this build does not know: export refuses to guess.
    let foreign = dir.join("foreign.mcap");
    {
        let mut w = mcap::WriteOptions::new()
            .profile("ros2")
            .create(std::io::BufWriter::new(
                std::fs::File::create(&foreign).unwrap(),
            ))
            .unwrap();
        let s = w
            .add_schema(TYPE_CONTACT_STEP, "ros2msg", b"float64 force")
            .unwrap();
        let c = w
            .add_channel(s, TOPIC_CONTACT_STEP, "cdr", &BTreeMap::new())
            .unwrap();
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: c,
                sequence: 1,
                log_time: 1,
                publish_time: 1,
            },
            &[0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 240, 63],
        )
        .unwrap();
        w.finish().unwrap();
    }
    assert!(
        recordings::info(&foreign).is_ok(),
        "info lists foreign definitions"
    );
    let e = recordings::export_csv(&foreign, &dir.join("csv")).unwrap_err();
    assert!(matches!(e, RecordingError::UnknownSchema { .. }), "{e}");

    // No physics steps at all: export says which topic is missing.
    let empty = dir.join("empty.mcap");
    SessionWriter::create(&empty, &RecordingConfig::default(), &SessionInfo::default())
        .unwrap()
        .finish(BTreeMap::new())
        .unwrap();
    let e = recordings::export_csv(&empty, &dir.join("csv")).unwrap_err();
    assert!(
        matches!(&e, RecordingError::MissingTopic { topic, .. } if topic == TOPIC_CONTACT_STEP),
        "{e}"
    );

    // repair refuses to overwrite its input.
    assert!(recordings::repair(&empty, &empty).is_err());
}

//! Length prefixes checked before the `mcap` crate parses a record.
//!
//! Why: the `mcap` crate (0.26, through binrw) reserves a string's or byte field's claimed
//! length before it reads it. A damaged u32 prefix inside an otherwise well-framed record
//! then asks for up to 4 GiB (the fuzz tests saw 0.8–1.6 GB for a 48 kB recording), long
//! before the parser notices the record is shorter. Walking the MCAP record layouts here
//! (MCAP spec, records 0x01–0x0F) finds the first record whose fields claim more bytes than
//! the record holds; the reader parses only the records before it.

/// One field of a record body, in order.
#[derive(Clone, Copy)]
enum Field {
    /// Fixed-size integer of this many bytes.
    Fixed(usize),
    /// u32 length, then that many bytes (a string or a byte field).
    Prefixed32,
    /// u64 length, then that many bytes.
    Prefixed64,
    /// u32 byte length of a map whose entries are two prefixed strings.
    StringMap,
    /// Everything left in the record (message data).
    Rest,
}

use Field::*;

/// The layout of each record kind that carries length prefixes; other kinds (messages,
/// footers, summary offsets, data end) have none that reserve memory.
fn layout(opcode: u8) -> Option<&'static [Field]> {
    Some(match opcode {
        // Header: profile, library.
        0x01 => &[Prefixed32, Prefixed32],
        // Schema: id, name, encoding, data.
        0x03 => &[Fixed(2), Prefixed32, Prefixed32, Prefixed32],
        // Channel: id, schema id, topic, message encoding, metadata.
        0x04 => &[Fixed(2), Fixed(2), Prefixed32, Prefixed32, StringMap],
        // Chunk: start, end, uncompressed size, CRC, compression, records.
        0x06 => &[
            Fixed(8),
            Fixed(8),
            Fixed(8),
            Fixed(4),
            Prefixed32,
            Prefixed64,
        ],
        // Message index: channel id, (log time, offset) array.
        0x07 => &[Fixed(2), Prefixed32],
        // Chunk index: start, end, offset, length, message index offsets (u16 → u64),
        // message index length, compression, compressed and uncompressed size.
        0x08 => &[
            Fixed(8),
            Fixed(8),
            Fixed(8),
            Fixed(8),
            Prefixed32,
            Fixed(8),
            Prefixed32,
            Fixed(8),
            Fixed(8),
        ],
        // Attachment: log time, create time, name, media type, data, CRC.
        0x09 => &[Fixed(8), Fixed(8), Prefixed32, Prefixed32, Prefixed64, Rest],
        // Attachment index: offset, length, log time, create time, data size, name, media.
        0x0A => &[
            Fixed(8),
            Fixed(8),
            Fixed(8),
            Fixed(8),
            Fixed(8),
            Prefixed32,
            Prefixed32,
        ],
        // Statistics: counts and times, then channel message counts (u16 → u64).
        0x0B => &[
            Fixed(8),
            Fixed(2),
            Fixed(4),
            Fixed(4),
            Fixed(4),
            Fixed(4),
            Fixed(8),
            Fixed(8),
            Prefixed32,
        ],
        // Metadata: name, string map.
        0x0C => &[Prefixed32, StringMap],
        // Metadata index: offset, length, name.
        0x0D => &[Fixed(8), Fixed(8), Prefixed32],
        _ => return None,
    })
}

fn u32_at(b: &[u8], at: usize) -> Option<u64> {
    b.get(at..at + 4)
        .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as u64)
}

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    b.get(at..at + 8).map(|s| {
        let mut a = [0u8; 8];
        a.copy_from_slice(s);
        u64::from_le_bytes(a)
    })
}

/// Checks one record body against its layout; the problem if a field claims more bytes
/// than remain.
fn check_body(opcode: u8, body: &[u8]) -> Result<(), String> {
    let Some(fields) = layout(opcode) else {
        return Ok(());
    };
    let mut at = 0usize;
    for (k, field) in fields.iter().enumerate() {
        let left = (body.len() - at.min(body.len())) as u64;
        let claim = |width: usize, len: Option<u64>| -> Result<usize, String> {
            let len = len.ok_or_else(|| format!("field {k} cut short"))?;
            if len > left.saturating_sub(width as u64) {
                return Err(format!(
                    "field {k} of record 0x{opcode:02x} claims {len} bytes, {} remain",
                    left.saturating_sub(width as u64)
                ));
            }
            Ok(width + len as usize)
        };
        at += match *field {
            Fixed(n) => {
                if (n as u64) > left {
                    return Err(format!("record 0x{opcode:02x} cut short at field {k}"));
                }
                n
            }
            Prefixed32 => claim(4, u32_at(body, at))?,
            Prefixed64 => claim(8, u64_at(body, at))?,
            StringMap => {
                let size = claim(4, u32_at(body, at))?;
                let map = &body[at + 4..at + size];
                let mut m = 0usize;
                while m < map.len() {
                    let left_in_map = (map.len() - m) as u64;
                    let len = u32_at(map, m).ok_or("map entry cut short")?;
                    if len > left_in_map.saturating_sub(4) {
                        return Err(format!(
                            "a map entry of record 0x{opcode:02x} claims {len} bytes, {} remain",
                            left_in_map.saturating_sub(4)
                        ));
                    }
                    m += 4 + len as usize;
                }
                size
            }
            Rest => return Ok(()),
        };
    }
    Ok(())
}

/// Walks the records in `records` (no magic) and returns the offset of the first one whose
/// fields claim more than it holds, with the problem. Stops without a finding at a record
/// that runs past the end: the reader reports that one itself (a torn tail).
pub fn first_overlong(records: &[u8]) -> Option<(usize, String)> {
    let mut at = 0usize;
    while at + 9 <= records.len() {
        let opcode = records[at];
        let len = u64_at(records, at + 1)?;
        let start = at + 9;
        if len > (records.len() - start) as u64 {
            return None;
        }
        let end = start + len as usize;
        if let Err(problem) = check_body(opcode, &records[start..end]) {
            return Some((at, problem));
        }
        at = end;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(opcode: u8, body: &[u8]) -> Vec<u8> {
        let mut r = vec![opcode];
        r.extend_from_slice(&(body.len() as u64).to_le_bytes());
        r.extend_from_slice(body);
        r
    }

    fn string(s: &str) -> Vec<u8> {
        let mut v = (s.len() as u32).to_le_bytes().to_vec();
        v.extend_from_slice(s.as_bytes());
        v
    }

    #[test]
    fn a_header_claiming_a_huge_string_is_found_and_a_good_one_passes() {
        let good = [string("ros2"), string("arthrosim")].concat();
        let mut file = record(0x01, &good);
        let mut bad = good.clone();
        bad[0..4].copy_from_slice(&0xF000_0000u32.to_le_bytes());
        let bad_at = file.len();
        file.extend(record(0x01, &bad));
        assert_eq!(first_overlong(&file[..bad_at]), None);
        let (at, problem) = first_overlong(&file).unwrap();
        assert_eq!(at, bad_at);
        assert!(problem.contains("4026531840 bytes"), "{problem}");
    }

    #[test]
    fn metadata_map_entries_are_checked_inside_the_map() {
        let mut map = [string("k"), string("v")].concat();
        let body = |map: &[u8]| {
            let mut b = string("summary");
            b.extend_from_slice(&(map.len() as u32).to_le_bytes());
            b.extend_from_slice(map);
            b
        };
        assert_eq!(first_overlong(&record(0x0C, &body(&map))), None);
        map[5..9].copy_from_slice(&1_000_000u32.to_le_bytes());
        assert!(first_overlong(&record(0x0C, &body(&map))).is_some());
    }

    #[test]
    fn a_record_running_past_the_end_is_left_to_the_reader() {
        let mut r = record(0x01, &string("ros2"));
        r.truncate(r.len() - 1);
        assert_eq!(first_overlong(&r), None);
    }
}

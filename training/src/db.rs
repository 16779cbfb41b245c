//! The trainee database: one SQLite file (bundled SQLite, WAL, busy timeout), explicit
//! numbered migrations, rows only ever added (a session's end time is filled in once).
//!
//! Opening refuses, without writing a byte: a file that is not an SQLite database (or fails
//! SQLite's quick check), an SQLite database of another application, and a database written
//! by a newer arthrosim (schema version above the ones this build knows).

use std::path::{Path, PathBuf};
use std::time::Duration;

use rusqlite::{params, Connection, OpenFlags, OptionalExtension, TransactionBehavior};
use serde::Serialize;

/// `PRAGMA application_id` of an arthrosim trainee database ("ARTH").
pub const APPLICATION_ID: i32 = 0x4152_5448;

/// The migrations, in order; `PRAGMA user_version` = how many have been applied.
pub const MIGRATIONS: &[&str] = &[
    // 1: trainees, training sessions, cases (one row per answered specimen).
    r#"
CREATE TABLE trainees (
    id INTEGER PRIMARY KEY,
    name TEXT NOT NULL UNIQUE,
    created_utc TEXT NOT NULL
);
CREATE TABLE sessions (
    id INTEGER PRIMARY KEY,
    trainee_id INTEGER NOT NULL REFERENCES trainees(id),
    started_utc TEXT NOT NULL,
    finished_utc TEXT,
    seed INTEGER NOT NULL,
    case_count INTEGER NOT NULL,
    grade_scales TEXT NOT NULL,
    operator TEXT NOT NULL,
    launch_origin TEXT NOT NULL,
    session_dir TEXT NOT NULL,
    recording_path TEXT,
    gap_report_path TEXT
);
CREATE TABLE cases (
    id INTEGER PRIMARY KEY,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    case_index INTEGER NOT NULL,
    true_grade INTEGER NOT NULL,
    modulus_scale REAL NOT NULL,
    answered_grade INTEGER NOT NULL,
    answer_source TEXT NOT NULL,
    response_time_s REAL NOT NULL,
    probings INTEGER NOT NULL,
    peak_normal_force_n REAL,
    mean_normal_force_n REAL,
    started_utc TEXT NOT NULL,
    answered_utc TEXT NOT NULL,
    UNIQUE (session_id, case_index)
);
CREATE INDEX cases_session ON cases(session_id);
CREATE INDEX sessions_trainee ON sessions(trainee_id);
"#,
];

pub const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

#[derive(Debug, thiserror::Error)]
pub enum DbError {
    #[error("trainee database {path}: not a usable SQLite database ({detail}); the file was left untouched")]
    Corrupt { path: PathBuf, detail: String },
    #[error("trainee database {path}: an SQLite database of another application (application_id {found:#x}); the file was left untouched")]
    Foreign { path: PathBuf, found: i32 },
    #[error("trainee database {path}: schema version {found} was written by a newer arthrosim (this one knows up to {known}); use a newer arthrosim or another --db")]
    NewerSchema {
        path: PathBuf,
        found: i64,
        known: i64,
    },
    #[error("trainee database {path}: cannot create its folder: {source}")]
    Folder {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("trainee database {path}: {source}")]
    Sql {
        path: PathBuf,
        #[source]
        source: rusqlite::Error,
    },
    #[error("trainee name {name:?}: {why}")]
    BadName { name: String, why: &'static str },
    #[error("no trainee named {0:?} in the database")]
    UnknownTrainee(String),
}

/// Refuses names that could not be used safely in a file name or a terminal.
pub fn check_trainee_name(name: &str) -> Result<(), DbError> {
    let bad = |why| {
        Err(DbError::BadName {
            name: name.to_string(),
            why,
        })
    };
    if name.trim().is_empty() {
        return bad("empty");
    }
    if name != name.trim() {
        return bad("leading or trailing white space");
    }
    if name.chars().count() > 64 {
        return bad("longer than 64 characters");
    }
    if name.contains(['/', '\\']) {
        return bad("contains a path separator");
    }
    if name.chars().any(char::is_control) {
        return bad("contains a control character");
    }
    if name == "." || name == ".." {
        return bad("not a name");
    }
    Ok(())
}

/// The per-user default: `$XDG_DATA_HOME/arthrosim/trainees.sqlite`, else
/// `~/.local/share/arthrosim/trainees.sqlite`.
pub fn default_path() -> PathBuf {
    let base = std::env::var_os("XDG_DATA_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/share")))
        .unwrap_or_else(|| PathBuf::from("."));
    base.join("arthrosim").join("trainees.sqlite")
}

/// How long a write waits for another process's write to finish.
const BUSY_TIMEOUT: Duration = Duration::from_secs(30);

/// Switches the file to WAL and returns the journal mode it is in. Changing the journal mode
/// takes an exclusive lock without going through the busy handler, so two processes opening
/// a new database at once can get `SQLITE_BUSY` here (seen in `two_writers_share_one_database`):
/// retried, like any other busy write, for up to `timeout`.
fn set_wal(conn: &Connection, timeout: Duration) -> Result<String, rusqlite::Error> {
    let deadline = std::time::Instant::now() + timeout;
    loop {
        match conn.query_row("PRAGMA journal_mode=WAL", [], |r| r.get::<_, String>(0)) {
            Err(rusqlite::Error::SqliteFailure(e, _))
                if e.code == rusqlite::ErrorCode::DatabaseBusy
                    && std::time::Instant::now() < deadline =>
            {
                std::thread::sleep(Duration::from_millis(5));
            }
            other => return other,
        }
    }
}

pub struct Db {
    conn: Connection,
    path: PathBuf,
}

/// A new training session's row.
#[derive(Debug, Clone)]
pub struct NewSession<'a> {
    pub trainee_id: i64,
    pub started_utc: &'a str,
    pub seed: u64,
    pub case_count: u32,
    pub grade_scales: &'a [f64],
    pub operator: &'a str,
    pub launch_origin: &'a str,
    pub session_dir: &'a str,
    pub recording_path: Option<&'a str>,
    pub gap_report_path: Option<&'a str>,
}

/// One answered specimen.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CaseRow {
    pub case_index: u32,
    pub true_grade: u32,
    pub modulus_scale: f64,
    pub answered_grade: u32,
    pub answer_source: String,
    pub response_time_s: f64,
    pub probings: u32,
    pub peak_normal_force_n: Option<f64>,
    pub mean_normal_force_n: Option<f64>,
    pub started_utc: String,
    pub answered_utc: String,
}

/// A session with its cases (for reports).
#[derive(Debug, Clone, Serialize)]
pub struct SessionRow {
    pub id: i64,
    pub trainee: String,
    pub started_utc: String,
    pub finished_utc: Option<String>,
    pub seed: i64,
    pub case_count: u32,
    pub grade_scales: Vec<f64>,
    pub operator: String,
    pub session_dir: String,
    pub recording_path: Option<String>,
    pub gap_report_path: Option<String>,
    pub cases: Vec<CaseRow>,
}

impl SessionRow {
    pub fn correct(&self) -> usize {
        self.cases
            .iter()
            .filter(|c| c.true_grade == c.answered_grade)
            .count()
    }

    /// Accuracy over the answered cases (None: nothing answered).
    pub fn accuracy(&self) -> Option<f64> {
        (!self.cases.is_empty()).then(|| self.correct() as f64 / self.cases.len() as f64)
    }
}

impl Db {
    /// Opens (creating it and its folder when missing) and migrates the database.
    pub fn open(path: &Path) -> Result<Db, DbError> {
        let sql = |source| DbError::Sql {
            path: path.to_path_buf(),
            source,
        };
        let existed = path.exists();
        if !existed {
            if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
                std::fs::create_dir_all(parent).map_err(|source| DbError::Folder {
                    path: path.to_path_buf(),
                    source,
                })?;
            }
        }
        if existed {
            check_existing(path)?;
        }
        let conn = Connection::open(path).map_err(sql)?;
        conn.busy_timeout(BUSY_TIMEOUT).map_err(sql)?;
        let mode = set_wal(&conn, BUSY_TIMEOUT).map_err(sql)?;
        if !mode.eq_ignore_ascii_case("wal") {
            tracing::warn!("{}: journal mode {mode}, not WAL", path.display());
        }
        conn.execute_batch("PRAGMA foreign_keys=ON; PRAGMA synchronous=NORMAL;")
            .map_err(sql)?;
        let mut db = Db {
            conn,
            path: path.to_path_buf(),
        };
        db.migrate()?;
        Ok(db)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn sql(&self, source: rusqlite::Error) -> DbError {
        DbError::Sql {
            path: self.path.clone(),
            source,
        }
    }

    /// Applies the missing migrations, each in its own immediate transaction (a second
    /// process opening the same new file waits, then finds it migrated).
    fn migrate(&mut self) -> Result<(), DbError> {
        loop {
            let path = self.path.clone();
            let sql = |source| DbError::Sql {
                path: path.clone(),
                source,
            };
            let tx = self
                .conn
                .transaction_with_behavior(TransactionBehavior::Immediate)
                .map_err(sql)?;
            let version: i64 = tx
                .query_row("PRAGMA user_version", [], |r| r.get(0))
                .map_err(sql)?;
            if version > SCHEMA_VERSION {
                return Err(DbError::NewerSchema {
                    path: path.clone(),
                    found: version,
                    known: SCHEMA_VERSION,
                });
            }
            if version == SCHEMA_VERSION {
                return Ok(());
            }
            tx.execute_batch(MIGRATIONS[version as usize])
                .map_err(sql)?;
            tx.execute_batch(&format!(
                "PRAGMA user_version = {}; PRAGMA application_id = {APPLICATION_ID};",
                version + 1
            ))
            .map_err(sql)?;
            tx.commit().map_err(sql)?;
        }
    }

    /// The trainee's id, creating the trainee on first use.
    pub fn trainee(&mut self, name: &str, now_utc: &str) -> Result<i64, DbError> {
        check_trainee_name(name)?;
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(|e| self_sql(&self.path, e))?;
        tx.execute(
            "INSERT OR IGNORE INTO trainees (name, created_utc) VALUES (?1, ?2)",
            params![name, now_utc],
        )
        .map_err(|e| self_sql(&self.path, e))?;
        let id = tx
            .query_row("SELECT id FROM trainees WHERE name = ?1", [name], |r| {
                r.get(0)
            })
            .map_err(|e| self_sql(&self.path, e))?;
        tx.commit().map_err(|e| self_sql(&self.path, e))?;
        Ok(id)
    }

    pub fn start_session(&mut self, s: &NewSession) -> Result<i64, DbError> {
        let scales = serde_json::to_string(s.grade_scales).unwrap_or_default();
        self.conn
            .execute(
                "INSERT INTO sessions (trainee_id, started_utc, seed, case_count, grade_scales, \
                 operator, launch_origin, session_dir, recording_path, gap_report_path) \
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
                params![
                    s.trainee_id,
                    s.started_utc,
                    s.seed as i64,
                    s.case_count,
                    scales,
                    s.operator,
                    s.launch_origin,
                    s.session_dir,
                    s.recording_path,
                    s.gap_report_path
                ],
            )
            .map_err(|e| self.sql(e))?;
        Ok(self.conn.last_insert_rowid())
    }

    /// Stores one answered case (a second answer for the same case is refused by the
    /// UNIQUE constraint: nothing is overwritten).
    pub fn add_case(&mut self, session_id: i64, c: &CaseRow) -> Result<(), DbError> {
        self.conn
            .execute(
                "INSERT INTO cases (session_id, case_index, true_grade, modulus_scale, \
                 answered_grade, answer_source, response_time_s, probings, peak_normal_force_n, \
                 mean_normal_force_n, started_utc, answered_utc) \
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12)",
                params![
                    session_id,
                    c.case_index,
                    c.true_grade,
                    c.modulus_scale,
                    c.answered_grade,
                    c.answer_source,
                    c.response_time_s,
                    c.probings,
                    c.peak_normal_force_n,
                    c.mean_normal_force_n,
                    c.started_utc,
                    c.answered_utc
                ],
            )
            .map_err(|e| self.sql(e))?;
        Ok(())
    }

    /// Fills in a session's end time (once; a finished session is never changed).
    pub fn finish_session(&mut self, session_id: i64, now_utc: &str) -> Result<(), DbError> {
        self.conn
            .execute(
                "UPDATE sessions SET finished_utc = ?2 WHERE id = ?1 AND finished_utc IS NULL",
                params![session_id, now_utc],
            )
            .map_err(|e| self.sql(e))?;
        Ok(())
    }

    pub fn trainee_names(&self) -> Result<Vec<String>, DbError> {
        let mut stmt = self
            .conn
            .prepare("SELECT name FROM trainees ORDER BY name")
            .map_err(|e| self.sql(e))?;
        let names = stmt
            .query_map([], |r| r.get(0))
            .and_then(|rows| rows.collect::<Result<Vec<String>, _>>())
            .map_err(|e| self.sql(e))?;
        Ok(names)
    }

    /// A trainee's sessions, oldest first, with their cases.
    pub fn sessions_of(&self, name: &str) -> Result<Vec<SessionRow>, DbError> {
        let id: Option<i64> = self
            .conn
            .query_row("SELECT id FROM trainees WHERE name = ?1", [name], |r| {
                r.get(0)
            })
            .optional()
            .map_err(|e| self.sql(e))?;
        let Some(id) = id else {
            return Err(DbError::UnknownTrainee(name.to_string()));
        };
        let mut stmt = self
            .conn
            .prepare(
                "SELECT id, started_utc, finished_utc, seed, case_count, grade_scales, operator, \
                 session_dir, recording_path, gap_report_path FROM sessions \
                 WHERE trainee_id = ?1 ORDER BY started_utc, id",
            )
            .map_err(|e| self.sql(e))?;
        let mut sessions = stmt
            .query_map([id], |r| {
                let scales: String = r.get(5)?;
                Ok(SessionRow {
                    id: r.get(0)?,
                    trainee: name.to_string(),
                    started_utc: r.get(1)?,
                    finished_utc: r.get(2)?,
                    seed: r.get(3)?,
                    case_count: r.get(4)?,
                    grade_scales: serde_json::from_str(&scales).unwrap_or_default(),
                    operator: r.get(6)?,
                    session_dir: r.get(7)?,
                    recording_path: r.get(8)?,
                    gap_report_path: r.get(9)?,
                    cases: Vec::new(),
                })
            })
            .and_then(|rows| rows.collect::<Result<Vec<_>, _>>())
            .map_err(|e| self.sql(e))?;
        let mut stmt = self
            .conn
            .prepare(
                "SELECT case_index, true_grade, modulus_scale, answered_grade, answer_source, \
                 response_time_s, probings, peak_normal_force_n, mean_normal_force_n, \
                 started_utc, answered_utc FROM cases WHERE session_id = ?1 ORDER BY case_index",
            )
            .map_err(|e| self.sql(e))?;
        for s in &mut sessions {
            s.cases = stmt
                .query_map([s.id], |r| {
                    Ok(CaseRow {
                        case_index: r.get(0)?,
                        true_grade: r.get(1)?,
                        modulus_scale: r.get(2)?,
                        answered_grade: r.get(3)?,
                        answer_source: r.get(4)?,
                        response_time_s: r.get(5)?,
                        probings: r.get(6)?,
                        peak_normal_force_n: r.get(7)?,
                        mean_normal_force_n: r.get(8)?,
                        started_utc: r.get(9)?,
                        answered_utc: r.get(10)?,
                    })
                })
                .and_then(|rows| rows.collect::<Result<Vec<_>, _>>())
                .map_err(|e| self.sql(e))?;
        }
        Ok(sessions)
    }
}

fn self_sql(path: &Path, source: rusqlite::Error) -> DbError {
    DbError::Sql {
        path: path.to_path_buf(),
        source,
    }
}

/// Read-only checks of an existing file before anything may write to it.
fn check_existing(path: &Path) -> Result<(), DbError> {
    let corrupt = |detail: String| DbError::Corrupt {
        path: path.to_path_buf(),
        detail,
    };
    let len = std::fs::metadata(path)
        .map_err(|e| corrupt(e.to_string()))?
        .len();
    if len == 0 {
        return Ok(()); // an empty file is an empty database to SQLite
    }
    let mut header = [0u8; 16];
    {
        use std::io::Read;
        let mut f = std::fs::File::open(path).map_err(|e| corrupt(e.to_string()))?;
        f.read_exact(&mut header)
            .map_err(|_| corrupt(format!("only {len} bytes, shorter than an SQLite header")))?;
    }
    if &header != b"SQLite format 3\0" {
        return Err(corrupt("no SQLite header".into()));
    }
    let conn = Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(|e| corrupt(e.to_string()))?;
    conn.busy_timeout(BUSY_TIMEOUT)
        .map_err(|e| corrupt(e.to_string()))?;
    let check: String = conn
        .query_row("PRAGMA quick_check", [], |r| r.get(0))
        .map_err(|e| corrupt(e.to_string()))?;
    if check != "ok" {
        return Err(corrupt(format!("quick_check: {check}")));
    }
    let app: i32 = conn
        .query_row("PRAGMA application_id", [], |r| r.get(0))
        .map_err(|e| corrupt(e.to_string()))?;
    let version: i64 = conn
        .query_row("PRAGMA user_version", [], |r| r.get(0))
        .map_err(|e| corrupt(e.to_string()))?;
    let tables: i64 = conn
        .query_row(
            "SELECT count(*) FROM sqlite_schema WHERE type = 'table'",
            [],
            |r| r.get(0),
        )
        .map_err(|e| corrupt(e.to_string()))?;
    if app != APPLICATION_ID && (app != 0 || tables > 0) {
        return Err(DbError::Foreign {
            path: path.to_path_buf(),
            found: app,
        });
    }
    if version > SCHEMA_VERSION {
        return Err(DbError::NewerSchema {
            path: path.to_path_buf(),
            found: version,
            known: SCHEMA_VERSION,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("training-db-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn case(i: u32, truth: u32, answer: u32) -> CaseRow {
        CaseRow {
            case_index: i,
            true_grade: truth,
            modulus_scale: 1.0 - 0.205 * truth as f64,
            answered_grade: answer,
            answer_source: "operator".into(),
            response_time_s: 3.0,
            probings: 3,
            peak_normal_force_n: Some(4.0),
            mean_normal_force_n: Some(2.0),
            started_utc: "2026-01-01T00:00:00Z".into(),
            answered_utc: "2026-01-01T00:00:03Z".into(),
        }
    }

    /// Cases stored for trainee `who` (0 before the trainee exists).
    fn cases_of(conn: &Connection, who: &str) -> i64 {
        conn.query_row(
            "SELECT count(*) FROM cases JOIN sessions ON cases.session_id = sessions.id \
             JOIN trainees ON sessions.trainee_id = trainees.id WHERE trainees.name = ?1",
            [who],
            |r| r.get(0),
        )
        .unwrap()
    }

    #[test]
    fn schema_has_the_documented_tables_and_nothing_is_overwritten() {
        let dir = scratch("schema");
        let path = dir.join("sub/trainees.sqlite");
        let mut db = Db::open(&path).unwrap();
        let t = db.trainee("Dr. Ada", "2026-01-01T00:00:00Z").unwrap();
        assert_eq!(db.trainee("Dr. Ada", "later").unwrap(), t);
        let s = db
            .start_session(&NewSession {
                trainee_id: t,
                started_utc: "2026-01-01T00:00:00Z",
                seed: 7,
                case_count: 2,
                grade_scales: &[1.0, 0.795, 0.59],
                operator: "emulated",
                launch_origin: "test",
                session_dir: "/tmp/x",
                recording_path: None,
                gap_report_path: None,
            })
            .unwrap();
        db.add_case(s, &case(1, 2, 2)).unwrap();
        assert!(
            db.add_case(s, &case(1, 0, 0)).is_err(),
            "a case is stored once"
        );
        db.finish_session(s, "2026-01-01T00:01:00Z").unwrap();
        db.finish_session(s, "2027").unwrap();
        let rows = db.sessions_of("Dr. Ada").unwrap();
        assert_eq!(
            rows[0].finished_utc.as_deref(),
            Some("2026-01-01T00:01:00Z")
        );
        assert_eq!(rows[0].cases, vec![case(1, 2, 2)]);
        drop(db);
        // What outside checks read.
        let conn = Connection::open(&path).unwrap();
        let n: i64 = conn
            .query_row(
                "SELECT count(*) FROM cases WHERE true_grade IS NOT NULL AND answered_grade IS NOT NULL",
                [],
                |r| r.get(0),
            )
            .unwrap();
        assert_eq!(n, 1);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn newer_schema_corrupt_and_foreign_files_are_refused_untouched() {
        let dir = scratch("refuse");
        let newer = dir.join("newer.sqlite");
        drop(Db::open(&newer).unwrap());
        {
            let c = Connection::open(&newer).unwrap();
            c.execute_batch("PRAGMA user_version = 99; PRAGMA wal_checkpoint(TRUNCATE);")
                .unwrap();
        }
        let before = std::fs::read(&newer).unwrap();
        let err = Db::open(&newer).err().unwrap().to_string();
        assert!(
            err.contains("newer arthrosim") && err.contains("99"),
            "{err}"
        );
        assert_eq!(std::fs::read(&newer).unwrap(), before);

        let corrupt = dir.join("corrupt.sqlite");
        let garbage: Vec<u8> = (0..8192u32)
            .map(|i| (i.wrapping_mul(2654435761) >> 24) as u8)
            .collect();
        std::fs::write(&corrupt, &garbage).unwrap();
        let err = Db::open(&corrupt).err().unwrap().to_string();
        assert!(
            err.contains("not a usable SQLite database") && err.contains("untouched"),
            "{err}"
        );
        assert_eq!(std::fs::read(&corrupt).unwrap(), garbage);
        assert!(!dir.join("corrupt.sqlite-wal").exists());

        // A real database whose pages were damaged after the header.
        let damaged = dir.join("damaged.sqlite");
        {
            let mut db = Db::open(&damaged).unwrap();
            db.trainee("x", "t").unwrap();
            db.conn
                .execute_batch("PRAGMA wal_checkpoint(TRUNCATE); PRAGMA journal_mode=DELETE;")
                .unwrap();
        }
        let mut bytes = std::fs::read(&damaged).unwrap();
        for b in bytes[4096..].iter_mut() {
            *b = 0xA5;
        }
        std::fs::write(&damaged, &bytes).unwrap();
        let err = Db::open(&damaged).err().unwrap().to_string();
        assert!(err.contains("not a usable"), "{err}");
        assert_eq!(std::fs::read(&damaged).unwrap(), bytes);

        let foreign = dir.join("foreign.sqlite");
        Connection::open(&foreign)
            .unwrap()
            .execute_batch("CREATE TABLE notes(x)")
            .unwrap();
        let err = Db::open(&foreign).err().unwrap().to_string();
        assert!(err.contains("another application"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn names_with_separators_or_control_characters_are_refused() {
        for bad in [
            "a/b",
            "a\\b",
            "x\ny",
            "tab\there",
            "",
            " pad",
            "..",
            "\u{1b}[31m",
        ] {
            assert!(check_trainee_name(bad).is_err(), "{bad:?}");
        }
        for good in ["Ada", "Dr. Müller", "trainee-07", "李"] {
            check_trainee_name(good).unwrap();
        }
    }

    /// Two processes append to one database at once: with WAL and the busy timeout neither
    /// fails, no row is lost, and the file passes SQLite's integrity check. The test runs
    /// itself twice as a child process (`TRAINING_DB_WRITER`). Each writer stops halfway
    /// until it sees the other's rows, so the two really write at the same time (alone, one
    /// child could finish its 150 rows before the other had started: the rows would not
    /// interleave, and the test would prove nothing about concurrency).
    #[test]
    fn two_writers_share_one_database() {
        const CASES: u32 = 150;
        if let Ok(spec) = std::env::var("TRAINING_DB_WRITER") {
            let (path, who) = spec.split_once('|').unwrap();
            let other = if who == "alice" { "bob" } else { "alice" };
            let mut db = Db::open(Path::new(path)).unwrap();
            let t = db.trainee(who, "now").unwrap();
            let s = db
                .start_session(&NewSession {
                    trainee_id: t,
                    started_utc: "now",
                    seed: 1,
                    case_count: CASES,
                    grade_scales: &[1.0, 0.59],
                    operator: "emulated",
                    launch_origin: "test",
                    session_dir: "/tmp",
                    recording_path: None,
                    gap_report_path: None,
                })
                .unwrap();
            for i in 1..=CASES {
                db.add_case(s, &case(i, i % 2, 0)).unwrap();
                if i == CASES / 2 {
                    let deadline = std::time::Instant::now() + Duration::from_secs(60);
                    while cases_of(&db.conn, other) == 0 {
                        assert!(
                            std::time::Instant::now() < deadline,
                            "{other} wrote nothing in 60 s"
                        );
                        std::thread::sleep(Duration::from_millis(2));
                    }
                }
            }
            db.finish_session(s, "end").unwrap();
            return;
        }
        let dir = scratch("writers");
        let path = dir.join("shared.sqlite");
        let exe = std::env::current_exe().unwrap();
        let children: Vec<_> = ["alice", "bob"]
            .iter()
            .map(|who| {
                std::process::Command::new(&exe)
                    .args([
                        "--exact",
                        "db::tests::two_writers_share_one_database",
                        "--nocapture",
                    ])
                    .env("TRAINING_DB_WRITER", format!("{}|{who}", path.display()))
                    .spawn()
                    .unwrap()
            })
            .collect();
        for mut c in children {
            assert!(c.wait().unwrap().success(), "a writer failed");
        }
        let db = Db::open(&path).unwrap();
        for who in ["alice", "bob"] {
            let s = db.sessions_of(who).unwrap();
            assert_eq!(s.len(), 1);
            assert_eq!(s[0].cases.len(), CASES as usize);
        }
        // The rows interleave: each writer added rows after the other's first ones.
        let span = |who: &str| -> (i64, i64) {
            db.conn
                .query_row(
                    "SELECT min(cases.id), max(cases.id) FROM cases \
                     JOIN sessions ON cases.session_id = sessions.id \
                     JOIN trainees ON sessions.trainee_id = trainees.id WHERE trainees.name = ?1",
                    [who],
                    |r| Ok((r.get(0)?, r.get(1)?)),
                )
                .unwrap()
        };
        let (a, b) = (span("alice"), span("bob"));
        assert!(a.0 < b.1 && b.0 < a.1, "alice {a:?}, bob {b:?}");
        let ok: String = db
            .conn
            .query_row("PRAGMA integrity_check", [], |r| r.get(0))
            .unwrap();
        assert_eq!(ok, "ok");
        let mode: String = db
            .conn
            .query_row("PRAGMA journal_mode", [], |r| r.get(0))
            .unwrap();
        assert_eq!(mode, "wal");
        let _ = std::fs::remove_dir_all(&dir);
    }
}

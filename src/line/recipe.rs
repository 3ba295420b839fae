//! The recipe: what a good sample of one film is, how the index is carried from sample to
//! sample, and where the results go. TOML, unknown keys refused; see
//! `config/recipes/demo.toml` for every key with its meaning.

use std::path::{Path, PathBuf};

use serde::Deserialize;

/// A recipe that cannot be used: one line naming the file, the key and the value at fault.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {problem}")]
pub struct RecipeError {
    /// The recipe file.
    pub path: PathBuf,
    /// What is wrong.
    pub problem: String,
}

/// A recipe.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    /// The film's name (e.g. "ZnS AR coat").
    pub film: String,
    /// The production line's name, the `line` label of every metric (default `line1`).
    #[serde(default = "line_default")]
    pub line: String,
    /// The production lot every record names (`inspect --lot` overrides it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lot: Option<String>,
    /// The operator every record names (`inspect --operator` overrides it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub operator: Option<String>,
    /// The film index.
    pub index: IndexSpec,
    /// The film thickness.
    pub thickness: ThicknessSpec,
    /// Acceptance beyond the thickness band.
    #[serde(default)]
    pub acceptance: Acceptance,
    /// Regions of interest (`[[roi]]`); none: the whole sensor.
    #[serde(default)]
    pub roi: Vec<Roi>,
    /// Control charts and run rules.
    #[serde(default)]
    pub spc: SpcSpec,
    /// What is kept on disk.
    #[serde(default)]
    pub retention: RetentionSpec,
    /// The MQTT broker the results go to (none: not published).
    #[serde(default)]
    pub mqtt: Option<MqttSpec>,
    /// The status page (none: not served).
    #[serde(default)]
    pub status: Option<StatusSpec>,
    /// The PLC's Modbus TCP server (none: not served).
    #[serde(default)]
    pub modbus: Option<ModbusSpec>,
    /// The reference sample `inspect --reference` measures (none: no reference check).
    #[serde(default)]
    pub reference: Option<ReferenceSpec>,
    /// The simulated line (`--sim` only).
    #[serde(default)]
    pub sim: SimSpec,
}

pub use crate::record::line::IndexMode;

/// `[index]`.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct IndexSpec {
    /// Nominal index (at 550 nm).
    pub nominal: f64,
    /// Allowed deviation from nominal (absolute).
    pub tolerance: f64,
    /// `hold`, `carry` or `solve` (default `carry`).
    #[serde(default = "carry")]
    pub mode: IndexMode,
    /// Hold and carry search within this much of the held index; a result further than
    /// half of it (or none) re-solves over the rig's whole range (default 0.02).
    #[serde(default = "resolve_default")]
    pub resolve_above: f64,
}

fn carry() -> IndexMode {
    IndexMode::Carry
}
fn resolve_default() -> f64 {
    0.02
}

/// `[thickness]`: give exactly one of `tolerance_nm` and `tolerance_percent`.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ThicknessSpec {
    /// Nominal thickness, nm.
    pub nominal_nm: f64,
    /// Allowed deviation of every pixel and of the mean, nm.
    #[serde(default)]
    pub tolerance_nm: Option<f64>,
    /// Allowed deviation, percent of nominal.
    #[serde(default)]
    pub tolerance_percent: Option<f64>,
    /// Largest standard deviation of the thickness over the judged pixels, nm.
    #[serde(default)]
    pub max_std_nm: Option<f64>,
}

impl ThicknessSpec {
    /// The tolerance in nm.
    pub fn tolerance(&self) -> f64 {
        match (self.tolerance_nm, self.tolerance_percent) {
            (Some(t), _) => t,
            (None, Some(p)) => self.nominal_nm * p / 100.0,
            (None, None) => 0.0,
        }
    }

    /// `[low, high]` nm.
    pub fn limits(&self) -> [f64; 2] {
        let t = self.tolerance();
        [self.nominal_nm - t, self.nominal_nm + t]
    }
}

/// `[acceptance]`.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Acceptance {
    /// Smallest share of judged pixels with a thickness (default 0.9).
    #[serde(default = "min_valid_default")]
    pub min_valid_fraction: f64,
    /// Largest connected out-of-tolerance region allowed, pixels (default 0: none).
    #[serde(default)]
    pub max_defect_area_px: usize,
}

fn min_valid_default() -> f64 {
    0.9
}

impl Default for Acceptance {
    fn default() -> Self {
        Self {
            min_valid_fraction: min_valid_default(),
            max_defect_area_px: 0,
        }
    }
}

/// `[[roi]]`: a rectangle of pixels judged.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
pub struct Roi {
    /// First column.
    pub x: usize,
    /// First row.
    pub y: usize,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl Roi {
    /// Whether pixel (x, y) is inside.
    pub fn contains(&self, x: usize, y: usize) -> bool {
        x >= self.x
            && x < self.x.saturating_add(self.width)
            && y >= self.y
            && y < self.y.saturating_add(self.height)
    }
}

/// `[spc]`.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SpcSpec {
    /// Samples kept in the rolling history (default 500).
    #[serde(default = "history_default")]
    pub history: usize,
    /// Samples the control limits are computed from: the oldest of the history (default 25).
    #[serde(default = "baseline_default")]
    pub baseline: usize,
    /// Fewest samples before limits and rules apply (default 8).
    #[serde(default = "min_points_default")]
    pub min_points: usize,
}

fn history_default() -> usize {
    500
}
fn baseline_default() -> usize {
    25
}
fn min_points_default() -> usize {
    8
}

impl Default for SpcSpec {
    fn default() -> Self {
        Self {
            history: history_default(),
            baseline: baseline_default(),
            min_points: min_points_default(),
        }
    }
}

/// Which raw sweeps are kept.
#[derive(Clone, Copy, Debug, Deserialize, serde::Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum RawPolicy {
    /// None.
    None,
    /// Those of failed samples.
    Failed,
    /// Every `every_n`-th sample's (and every failed one's).
    EveryNth,
    /// All.
    All,
}

/// `[retention]`.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RetentionSpec {
    /// `none`, `failed` (default), `every_nth` or `all`.
    #[serde(default = "failed")]
    pub raw: RawPolicy,
    /// For `every_nth`.
    #[serde(default = "every_default")]
    pub every_n: u64,
    /// Most bytes the kept raw sweeps may take; the oldest go first (default 1 GiB).
    #[serde(default = "budget_default")]
    pub raw_budget_bytes: u64,
    /// `results.jsonl` is rotated past this size (default 64 MiB).
    #[serde(default = "rotate_default")]
    pub results_rotate_bytes: u64,
    /// Rotated results files kept (default 8).
    #[serde(default = "rotated_keep_default")]
    pub results_keep: usize,
    /// Free bytes the output's file system must keep: below it no sample is measured and
    /// an alarm is raised (default 1 GiB).
    #[serde(default = "min_free_default")]
    pub min_free_bytes: u64,
}

fn failed() -> RawPolicy {
    RawPolicy::Failed
}
fn every_default() -> u64 {
    10
}
fn budget_default() -> u64 {
    1 << 30
}
fn rotate_default() -> u64 {
    64 << 20
}
fn rotated_keep_default() -> usize {
    8
}
fn min_free_default() -> u64 {
    1 << 30
}

impl Default for RetentionSpec {
    fn default() -> Self {
        Self {
            raw: failed(),
            every_n: every_default(),
            raw_budget_bytes: budget_default(),
            results_rotate_bytes: rotate_default(),
            results_keep: rotated_keep_default(),
            min_free_bytes: min_free_default(),
        }
    }
}

/// `[mqtt]`.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MqttSpec {
    /// Broker host (default 127.0.0.1); with TLS, the name its certificate is checked for.
    #[serde(default = "localhost")]
    pub host: String,
    /// Broker port (default 1883).
    #[serde(default = "mqtt_port")]
    pub port: u16,
    /// Topics: `<prefix>/sample` (retained: the last result), `<prefix>/alarm`,
    /// `<prefix>/status` (`online`, or `offline` as the last will; retained) (default
    /// `filmscope`).
    #[serde(default = "prefix_default")]
    pub prefix: String,
    /// Client id (default `filmscope-inspect`).
    #[serde(default = "client_default")]
    pub client_id: String,
    /// User name (none: anonymous).
    #[serde(default)]
    pub username: Option<String>,
    /// Password of `username`, written in the recipe; `password_file` keeps it out. Never
    /// written back (each sample's `summary.json` records the recipe's settings).
    #[serde(default, skip_serializing)]
    pub password: Option<String>,
    /// File whose first line is the password of `username` (relative to the recipe's
    /// folder), readable by its owner only: the recipe can then be shared and versioned.
    #[serde(default)]
    pub password_file: Option<PathBuf>,
    /// PEM file of the certificate authority the broker's certificate is checked against;
    /// given, the connection is TLS (relative to the recipe's folder).
    #[serde(default)]
    pub ca_file: Option<PathBuf>,
    /// PEM file of the client certificate (with `client_key_file`), for brokers that ask
    /// for one.
    #[serde(default)]
    pub client_cert_file: Option<PathBuf>,
    /// PEM file of the client certificate's private key.
    #[serde(default)]
    pub client_key_file: Option<PathBuf>,
    /// Seconds a connected broker may leave a record unacknowledged before an alarm, and
    /// the wait for acknowledgements at exit (default 10).
    #[serde(default = "ack_timeout_default")]
    pub ack_timeout_s: f64,
    /// Most unacknowledged records held for sending; the rest wait in `results.jsonl` for
    /// the next start (default 10000).
    #[serde(default = "spool_default")]
    pub spool_records: usize,
}

fn localhost() -> String {
    "127.0.0.1".into()
}
fn mqtt_port() -> u16 {
    1883
}
fn prefix_default() -> String {
    "filmscope".into()
}
fn client_default() -> String {
    "filmscope-inspect".into()
}
fn ack_timeout_default() -> f64 {
    10.0
}
fn spool_default() -> usize {
    10_000
}

/// Whether `inspect` measures continuously or when a PLC asks.
#[derive(Clone, Copy, Debug, Default, Deserialize, serde::Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Trigger {
    /// One sample after the other.
    #[default]
    None,
    /// Each sample when a PLC sets the Modbus trigger coil.
    Modbus,
}

/// `[modbus]`: the PLC's Modbus TCP server (`src/line/plc.rs` has the register map).
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ModbusSpec {
    /// `host:port` to listen on (default `127.0.0.1:1502`; port 0: any free one, printed).
    #[serde(default = "modbus_bind_default")]
    pub bind: String,
    /// `none` (default): measure continuously; `modbus`: wait for the trigger coil.
    #[serde(default)]
    pub trigger: Trigger,
}

fn modbus_bind_default() -> String {
    "127.0.0.1:1502".into()
}

/// `[status]`.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StatusSpec {
    /// Address to listen on (default 127.0.0.1).
    #[serde(default = "localhost")]
    pub bind: String,
    /// Port (default 8088; 0: any free one, printed).
    #[serde(default = "status_port")]
    pub port: u16,
    /// Seconds without a new sample after which the page shows STALE (default 600).
    #[serde(default = "stale_after_default")]
    pub stale_after_s: f64,
}

fn status_port() -> u16 {
    8088
}

fn line_default() -> String {
    "line1".into()
}

fn stale_after_default() -> f64 {
    600.0
}

/// `[reference]`: a certified sample measured at the start of a shift (`inspect
/// --reference`), its drift recorded and alarmed beyond tolerance.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ReferenceSpec {
    /// The reference's name (its certificate's id).
    pub name: String,
    /// Certified mean thickness, nm.
    pub thickness_nm: f64,
    /// Certified index at 550 nm.
    pub index: f64,
    /// Largest tolerated |measured - certified| mean thickness, nm.
    pub tolerance_nm: f64,
    /// Largest tolerated |measured - certified| index.
    pub tolerance_index: f64,
}

/// `[sim]`: the simulated line behind `--sim`.
#[derive(Clone, Debug, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SimSpec {
    /// Seed of the sample sequence (default 1).
    #[serde(default = "one")]
    pub seed: u64,
    /// Thickness drift per sample, nm (default 0.3).
    #[serde(default = "drift_default")]
    pub drift_nm_per_sample: f64,
    /// Every how many samples an out-of-tolerance one comes (default 7; 0: never).
    #[serde(default = "defect_every_default")]
    pub defect_every: u64,
}

fn one() -> u64 {
    1
}
fn drift_default() -> f64 {
    0.3
}
fn defect_every_default() -> u64 {
    7
}

impl Default for SimSpec {
    fn default() -> Self {
        Self {
            seed: 1,
            drift_nm_per_sample: drift_default(),
            defect_every: defect_every_default(),
        }
    }
}

/// Most bytes of a recipe file.
pub const MAX_RECIPE_BYTES: u64 = 1 << 20;
/// Most characters of the film's name.
pub const MAX_NAME: usize = 200;
/// Most nm of a nominal thickness or tolerance.
pub const MAX_THICKNESS_NM: f64 = 50_000.0;
/// Most pixels of a defect area (a 64 MP sensor).
pub const MAX_PIXELS: u64 = 1 << 26;
/// Most `[[roi]]` rectangles.
pub const MAX_ROIS: usize = 256;
/// Most samples of the SPC history (`spc.history`): a few MB of points, and start-up reads
/// back at most this many sample records.
pub const MAX_HISTORY: u64 = 10_000;
/// Most bytes of `raw_budget_bytes` and `min_free_bytes` (1 PiB).
pub const MAX_BYTES: u64 = 1 << 50;
/// Most bytes of a results file before it rotates (1 GiB).
pub const MAX_ROTATE_BYTES: u64 = 1 << 30;
/// Most rotated results files (a rotation renames each once).
pub const MAX_RESULTS_KEEP: u64 = 1000;
/// Most characters of an MQTT topic prefix.
pub const MAX_TOPIC: usize = 256;
/// Most characters of an MQTT user name or password.
pub const MAX_CREDENTIAL: usize = 256;
/// Most unacknowledged records held for sending.
pub const MAX_SPOOL: u64 = 100_000;
/// Most characters of an MQTT client id.
pub const MAX_CLIENT_ID: usize = 128;

/// The password in `path`'s first line (`mqtt.password_file`): the file readable by its
/// owner only (on Unix), the line at most [`MAX_CREDENTIAL`] characters.
fn read_password(path: &Path) -> Result<String, String> {
    let key = format!("mqtt.password_file = {:?}", path.display().to_string());
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt as _;
        let mode = std::fs::metadata(path)
            .map_err(|e| format!("{key}: cannot read: {e}"))?
            .permissions()
            .mode();
        if mode & 0o077 != 0 {
            return Err(format!(
                "{key}: readable by others (mode {:o}): `chmod 600` it",
                mode & 0o777
            ));
        }
    }
    let text = crate::limits::read_small(path, 4 * MAX_CREDENTIAL as u64 + 2)
        .map_err(|e| format!("{key}: cannot read: {e}"))?;
    let line = text.lines().next().unwrap_or_default();
    if line.is_empty() || line.chars().count() > MAX_CREDENTIAL {
        return Err(format!(
            "{key}: expected the password on its first line, 1 to {MAX_CREDENTIAL} characters"
        ));
    }
    Ok(line.to_owned())
}

impl Recipe {
    /// Reads and checks a recipe file.
    pub fn load(path: &Path) -> Result<Self, RecipeError> {
        let text = crate::limits::read_small(path, MAX_RECIPE_BYTES).map_err(|e| RecipeError {
            path: path.to_owned(),
            problem: format!("cannot read: {e}"),
        })?;
        let mut recipe = Self::parse(&text, path)?;
        recipe.check_files(path).map_err(|problem| RecipeError {
            path: path.to_owned(),
            problem,
        })?;
        Ok(recipe)
    }

    /// Resolves the files the recipe names against its folder and reads them: a TLS file
    /// that is missing or does not parse is refused here, before anything starts.
    fn check_files(&mut self, path: &Path) -> Result<(), String> {
        let dir = path.parent().unwrap_or(Path::new("."));
        if let Some(m) = &mut self.mqtt {
            for f in [
                &mut m.ca_file,
                &mut m.client_cert_file,
                &mut m.client_key_file,
            ]
            .into_iter()
            .flatten()
            {
                if f.is_relative() {
                    *f = dir.join(&*f);
                }
            }
            if let Some(f) = &mut m.password_file {
                if f.is_relative() {
                    *f = dir.join(&*f);
                }
                m.password = Some(read_password(f)?);
            }
            if let Some(ca) = &m.ca_file {
                let client = m
                    .client_cert_file
                    .as_deref()
                    .zip(m.client_key_file.as_deref());
                super::tls::client_config(ca, client).map_err(|e| e.to_string())?;
            }
        }
        Ok(())
    }

    /// Parses and checks recipe text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, RecipeError> {
        let err = |problem: String| RecipeError {
            path: path.to_owned(),
            problem,
        };
        let recipe: Recipe = toml::from_str(text).map_err(|e| err(toml_line(&e, text)))?;
        recipe.check().map_err(err)?;
        Ok(recipe)
    }

    /// The recipe with the lot and operator the command line gives in place of its own,
    /// checked as the recipe's are.
    pub fn with_labels(
        mut self,
        lot: Option<String>,
        operator: Option<String>,
    ) -> Result<Self, BadLabel> {
        self.lot = lot.or(self.lot);
        self.operator = operator.or(self.operator);
        self.check_ranges().map_err(BadLabel)?;
        Ok(self)
    }

    /// The checks beyond the types: each names its key, its value and the range it must
    /// lie in (`config/recipes/demo.toml` gives each key's meaning).
    fn check(&self) -> Result<(), String> {
        self.check_shapes()?;
        self.check_ranges()
    }

    /// Every number within a stated range, every text of a sane length: no value can make
    /// start-up, a rotation or a history allocation unbounded.
    fn check_ranges(&self) -> Result<(), String> {
        self.check_measurement_ranges()?;
        self.check_history_ranges()?;
        self.check_service_ranges()?;
        num_in(
            "sim.drift_nm_per_sample",
            self.sim.drift_nm_per_sample,
            -100.0,
            100.0,
        )?;
        int_in("sim.defect_every", self.sim.defect_every, 0, 1_000_000)?;
        Ok(())
    }

    /// The ranges of what is measured and judged: names and labels, the status page's
    /// staleness, the reference sample, the index, the thickness, the acceptance and the
    /// regions of interest.
    fn check_measurement_ranges(&self) -> Result<(), String> {
        text_in("film", &self.film, MAX_NAME)?;
        text_in("line", &self.line, MAX_NAME)?;
        if let Some(st) = &self.status {
            num_in("status.stale_after_s", st.stale_after_s, 1.0, 86_400.0)?;
        }
        if let Some(r) = &self.reference {
            text_in("reference.name", &r.name, MAX_NAME)?;
            num_in(
                "reference.thickness_nm",
                r.thickness_nm,
                0.0,
                MAX_THICKNESS_NM,
            )?;
            num_in("reference.index", r.index, 1.0, 6.0)?;
            num_in(
                "reference.tolerance_nm",
                r.tolerance_nm,
                0.0,
                MAX_THICKNESS_NM,
            )?;
            num_in("reference.tolerance_index", r.tolerance_index, 0.0, 1.0)?;
        }
        for (key, v) in [("lot", &self.lot), ("operator", &self.operator)] {
            if let Some(v) = v {
                text_in(key, v, MAX_NAME)?;
            }
        }
        num_in("index.nominal", self.index.nominal, 1.0, 6.0)?;
        num_in("index.tolerance", self.index.tolerance, 0.0, 1.0)?;
        num_in("index.resolve_above", self.index.resolve_above, 0.0, 5.0)?;
        let t = &self.thickness;
        num_in("thickness.nominal_nm", t.nominal_nm, 0.0, MAX_THICKNESS_NM)?;
        if let Some(v) = t.tolerance_nm {
            num_in("thickness.tolerance_nm", v, 0.0, MAX_THICKNESS_NM)?;
        }
        if let Some(v) = t.max_std_nm {
            num_in("thickness.max_std_nm", v, 0.0, MAX_THICKNESS_NM)?;
        }
        usize_in(
            "acceptance.max_defect_area_px",
            self.acceptance.max_defect_area_px,
            0,
            MAX_PIXELS,
        )?;
        if self.roi.len() > MAX_ROIS {
            return Err(format!(
                "roi: {} rectangles: expected at most {MAX_ROIS}",
                self.roi.len()
            ));
        }
        Ok(())
    }

    /// The ranges of what the line keeps: the SPC history and the retention of raw data and
    /// results.
    fn check_history_ranges(&self) -> Result<(), String> {
        let sp = &self.spc;
        usize_in("spc.history", sp.history, 2, MAX_HISTORY)?;
        usize_in("spc.baseline", sp.baseline, 2, sp.history as u64)?;
        usize_in("spc.min_points", sp.min_points, 2, sp.history as u64)?;
        let r = &self.retention;
        int_in("retention.every_n", r.every_n, 1, 1_000_000)?;
        int_in(
            "retention.raw_budget_bytes",
            r.raw_budget_bytes,
            0,
            MAX_BYTES,
        )?;
        int_in(
            "retention.results_rotate_bytes",
            r.results_rotate_bytes,
            4096,
            MAX_ROTATE_BYTES,
        )?;
        usize_in(
            "retention.results_keep",
            r.results_keep,
            1,
            MAX_RESULTS_KEEP,
        )?;
        int_in("retention.min_free_bytes", r.min_free_bytes, 0, MAX_BYTES)
    }

    /// The ranges of the services the line talks through: MQTT, the status page and
    /// Modbus.
    fn check_service_ranges(&self) -> Result<(), String> {
        if let Some(m) = &self.mqtt {
            text_in("mqtt.host", &m.host, 253)?;
            if m.host.contains(char::is_whitespace) {
                return Err(format!("mqtt.host = {:?}: a host name or address", m.host));
            }
            int_in("mqtt.port", m.port, 1, 65_535)?;
            text_in("mqtt.prefix", &m.prefix, MAX_TOPIC)?;
            text_in("mqtt.client_id", &m.client_id, MAX_CLIENT_ID)?;
            if let Some(u) = &m.username {
                text_in("mqtt.username", u, MAX_CREDENTIAL)?;
            }
            if let Some(p) = &m.password {
                if p.chars().count() > MAX_CREDENTIAL {
                    return Err(format!(
                        "mqtt.password: expected at most {MAX_CREDENTIAL} characters"
                    ));
                }
            }
            num_in("mqtt.ack_timeout_s", m.ack_timeout_s, 0.1, 3600.0)?;
            usize_in("mqtt.spool_records", m.spool_records, 1, MAX_SPOOL)?;
        }
        if let Some(st) = &self.status {
            text_in("status.bind", &st.bind, 253)?;
        }
        if let Some(mb) = &self.modbus {
            text_in("modbus.bind", &mb.bind, 253)?;
            let port = mb.bind.rsplit_once(':').map(|(_, p)| p.parse::<u16>());
            if !matches!(port, Some(Ok(_))) {
                return Err(format!(
                    "modbus.bind = {:?}: expected host:port (port 0 to 65535)",
                    mb.bind
                ));
            }
        }
        Ok(())
    }

    /// The checks of signs, pairs and combinations.
    fn check_shapes(&self) -> Result<(), String> {
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("{key} = {v}: must be a positive number"))
            }
        };
        if self.film.trim().is_empty() {
            return Err("film = \"\": give the film's name".into());
        }
        positive("index.nominal", self.index.nominal)?;
        positive("index.tolerance", self.index.tolerance)?;
        positive("index.resolve_above", self.index.resolve_above)?;
        positive("thickness.nominal_nm", self.thickness.nominal_nm)?;
        match (
            self.thickness.tolerance_nm,
            self.thickness.tolerance_percent,
        ) {
            (Some(_), Some(_)) => {
                return Err(
                    "thickness: both tolerance_nm and tolerance_percent given: give one".into(),
                )
            }
            (None, None) => {
                return Err("thickness: give tolerance_nm or tolerance_percent".into());
            }
            (Some(t), None) => positive("thickness.tolerance_nm", t)?,
            (None, Some(p)) => {
                positive("thickness.tolerance_percent", p)?;
                if p >= 100.0 {
                    return Err(format!(
                        "thickness.tolerance_percent = {p}: must be below 100"
                    ));
                }
            }
        }
        if let Some(s) = self.thickness.max_std_nm {
            positive("thickness.max_std_nm", s)?;
        }
        let v = self.acceptance.min_valid_fraction;
        if !(0.0..=1.0).contains(&v) {
            return Err(format!(
                "acceptance.min_valid_fraction = {v}: must be within 0..1"
            ));
        }
        for (i, r) in self.roi.iter().enumerate() {
            if r.width == 0 || r.height == 0 {
                return Err(format!(
                    "roi[{i}]: width = {}, height = {}: an empty rectangle",
                    r.width, r.height
                ));
            }
        }
        if self.spc.history < 2 {
            return Err(format!(
                "spc.history = {}: keep at least 2 samples",
                self.spc.history
            ));
        }
        if self.spc.baseline < 2 || self.spc.min_points < 2 {
            return Err(format!(
                "spc.baseline = {}, spc.min_points = {}: both at least 2",
                self.spc.baseline, self.spc.min_points
            ));
        }
        if self.retention.raw == RawPolicy::EveryNth && self.retention.every_n == 0 {
            return Err("retention.every_n = 0: must be at least 1".into());
        }
        if let Some(m) = &self.mqtt {
            if m.prefix.is_empty()
                || m.prefix.contains(['+', '#'])
                || m.prefix.starts_with('/')
                || m.prefix.ends_with('/')
            {
                return Err(format!(
                    "mqtt.prefix = {:?}: a topic prefix without wildcards or a leading or trailing /",
                    m.prefix
                ));
            }
            if m.username.is_none() && m.password.is_some() {
                return Err("mqtt.password: given without mqtt.username".into());
            }
            if m.password_file.is_some() {
                if m.password.is_some() {
                    return Err("mqtt.password, mqtt.password_file: give one, not both".into());
                }
                if m.username.is_none() {
                    return Err("mqtt.password_file: given without mqtt.username".into());
                }
            }
            if m.client_cert_file.is_some() != m.client_key_file.is_some() {
                return Err(
                    "mqtt.client_cert_file, mqtt.client_key_file: give both or neither".into(),
                );
            }
            if m.client_cert_file.is_some() && m.ca_file.is_none() {
                return Err("mqtt.client_cert_file: needs mqtt.ca_file (TLS)".into());
            }
        }
        Ok(())
    }

    /// Checks the recipe against a sensor of `width` x `height` pixels.
    pub fn check_sensor(&self, width: usize, height: usize) -> Result<(), RoiOutside> {
        for (index, r) in self.roi.iter().enumerate() {
            if r.x.saturating_add(r.width) > width || r.y.saturating_add(r.height) > height {
                return Err(RoiOutside {
                    index,
                    roi: [r.x, r.y, r.width, r.height],
                    sensor: [width, height],
                });
            }
        }
        Ok(())
    }
}

/// `key = v` within `lo..=hi`, or the error saying so.
fn int_in<T: Into<u64> + Copy + std::fmt::Display>(
    key: &str,
    v: T,
    lo: u64,
    hi: u64,
) -> Result<(), String> {
    if (lo..=hi).contains(&v.into()) {
        Ok(())
    } else {
        Err(format!("{key} = {v}: expected {lo} to {hi}"))
    }
}

/// [`int_in`] for a count.
fn usize_in(key: &str, v: usize, lo: u64, hi: u64) -> Result<(), String> {
    int_in(key, v as u64, lo, hi)
}

/// `key = v` finite and within `lo..=hi`, or the error saying so (a value far from 1 in
/// exponent notation).
fn num_in(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), String> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else if v.is_finite() && v != 0.0 && !(1e-6..1e9).contains(&v.abs()) {
        Err(format!("{key} = {v:e}: expected {lo} to {hi}"))
    } else {
        Err(format!("{key} = {v}: expected {lo} to {hi}"))
    }
}

/// `key = v` of 1 to `max` characters, not blank and without control characters, or the
/// error saying so (quoting at most 40 of them).
fn text_in(key: &str, v: &str, max: usize) -> Result<(), String> {
    if v.trim().is_empty() || v.chars().count() > max || v.chars().any(char::is_control) {
        Err(format!(
            "{key} = {:?}: expected 1 to {max} characters, no control characters",
            v.chars().take(40).collect::<String>()
        ))
    } else {
        Ok(())
    }
}

/// A lot or operator given on the command line that the recipe's checks refuse.
#[derive(Debug, thiserror::Error)]
#[error("--lot/--operator: {0}")]
pub struct BadLabel(pub String);

/// A region of interest outside the sensor.
#[derive(Debug, thiserror::Error)]
#[error("roi[{index}] = {{ x = {}, y = {}, width = {}, height = {} }}: outside the {} x {} sensor", roi[0], roi[1], roi[2], roi[3], sensor[0], sensor[1])]
pub struct RoiOutside {
    /// Which region.
    pub index: usize,
    /// Its x, y, width and height, pixels.
    pub roi: [usize; 4],
    /// The sensor's width and height, pixels.
    pub sensor: [usize; 2],
}

/// A TOML error in one line: the key path and the problem, with the line number.
fn toml_line(e: &toml::de::Error, text: &str) -> String {
    let msg = e.message().replace('\n', " ");
    match e.span() {
        Some(span) => {
            let before = text.as_bytes().get(..span.start).unwrap_or(text.as_bytes());
            let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
            let snippet = text
                .get(span.start..span.end)
                .unwrap_or("")
                .lines()
                .next()
                .unwrap_or("")
                .trim();
            // The key the value belongs to: its line's text before `=`, under its table.
            let whole = text.lines().nth(line - 1).unwrap_or("");
            let key = whole.split_once('=').map(|(k, _)| k.trim()).unwrap_or("");
            let table = text
                .lines()
                .take(line - 1)
                .filter(|l| l.trim_start().starts_with('['))
                .last()
                .and_then(|l| l.trim().trim_matches(['[', ']']).split(']').next())
                .map(|t| format!("{}.", t.trim()))
                .unwrap_or_default();
            if key.is_empty() || key.starts_with('[') {
                format!("line {line}: {msg} (at {snippet:?})")
            } else {
                let key: String = format!("{table}{key}").chars().take(80).collect();
                let key = crate::limits::printable(&key);
                format!("line {line}: {key}: {msg} (at {snippet:?})")
            }
        }
        None => msg,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) const DEMO: &str = include_str!("../../config/recipes/demo.toml");

    fn parse(t: &str) -> Result<Recipe, String> {
        Recipe::parse(t, Path::new("r.toml")).map_err(|e| e.to_string())
    }

    #[test]
    fn demo_recipe_parses() {
        let r = parse(DEMO).expect("demo");
        assert_eq!(r.index.mode, IndexMode::Carry);
        assert!(r.thickness.tolerance() > 0.0);
        assert!(r.mqtt.is_some());
    }

    const MIN: &str = "film = \"f\"\n[index]\nnominal = 2.1\ntolerance = 0.03\n[thickness]\nnominal_nm = 600\ntolerance_percent = 5\n";

    #[test]
    fn defaults_and_percent() {
        let r = parse(MIN).expect("min");
        assert_eq!(r.thickness.limits(), [570.0, 630.0]);
        assert_eq!(r.retention.raw, RawPolicy::Failed);
        assert_eq!(r.spc.history, 500);
        assert!(r.mqtt.is_none());
    }

    #[test]
    fn hostile_values_are_refused_with_their_range() {
        for (extra, line) in [
            (
                "[retention]\nresults_keep = 1_000_000_000\n",
                "r.toml: retention.results_keep = 1000000000: expected 1 to 1000",
            ),
            (
                "[spc]\nhistory = 1_000_000_000\n",
                "r.toml: spc.history = 1000000000: expected 2 to 10000",
            ),
            (
                "[spc]\nhistory = 1_000_000_000_000_000_000\n",
                "r.toml: spc.history = 1000000000000000000: expected 2 to 10000",
            ),
            (
                "[retention]\nresults_rotate_bytes = 1_000_000_000_000_000_000\n",
                "r.toml: retention.results_rotate_bytes = 1000000000000000000: expected 4096 to 1073741824",
            ),
            (
                "[retention]\nmin_free_bytes = 9_000_000_000_000_000_000\n",
                "r.toml: retention.min_free_bytes = 9000000000000000000: expected 0 to 1125899906842624",
            ),
            (
                "[spc]\nhistory = 10\nbaseline = 25\n",
                "r.toml: spc.baseline = 25: expected 2 to 10",
            ),
            (
                "[mqtt]\nport = 0\n",
                "r.toml: mqtt.port = 0: expected 1 to 65535",
            ),
            (
                "[sim]\ndrift_nm_per_sample = 1e300\n",
                "r.toml: sim.drift_nm_per_sample = 1e300: expected -100 to 100",
            ),
            (
                "[mqtt]\nspool_records = 0\n",
                "r.toml: mqtt.spool_records = 0: expected 1 to 100000",
            ),
            (
                "[mqtt]\nack_timeout_s = 1e9\n",
                "r.toml: mqtt.ack_timeout_s = 1e9: expected 0.1 to 3600",
            ),
            (
                "[mqtt]\nclient_cert_file = \"c.pem\"\n",
                "r.toml: mqtt.client_cert_file, mqtt.client_key_file: give both or neither",
            ),
            (
                "[mqtt]\nusername = \"u\"\npassword = \"x\"\npassword_file = \"p\"\n",
                "r.toml: mqtt.password, mqtt.password_file: give one, not both",
            ),
            (
                "[mqtt]\npassword_file = \"p\"\n",
                "r.toml: mqtt.password_file: given without mqtt.username",
            ),
            (
                "[modbus]\nbind = \"127.0.0.1\"\n",
                "r.toml: modbus.bind = \"127.0.0.1\": expected host:port (port 0 to 65535)",
            ),
        ] {
            let e = parse(&format!("{MIN}{extra}")).expect_err(extra);
            assert_eq!(e, line);
        }
        let e = parse(&format!(
            "{MIN}[mqtt]\nclient_id = \"{}\"\n",
            "c".repeat(500)
        ))
        .expect_err("long id");
        assert!(e.starts_with("r.toml: mqtt.client_id = \"cccc"), "{e}");
        let e = parse(&MIN.replace("nominal = 2.1", "nominal = 60")).expect_err("index");
        assert_eq!(e, "r.toml: index.nominal = 60: expected 1 to 6");
    }

    #[test]
    fn errors_name_file_key_and_value() {
        let e = parse(&MIN.replace("tolerance = 0.03", "tolerance = -1")).expect_err("an error");
        assert_eq!(e, "r.toml: index.tolerance = -1: must be a positive number");
        let e = parse(&format!("{MIN}colour = 3\n")).expect_err("an error");
        assert!(
            e.starts_with("r.toml: line 8: thickness.colour: unknown field `colour`"),
            "{e}"
        );
        assert!(!e.contains('\n'));
        let e = parse(
            &MIN.replace("mode", "x")
                .replace("[index]", "[index]\nmode = \"sometimes\""),
        )
        .expect_err("an error");
        assert!(e.contains("line 3") && e.contains("sometimes"), "{e}");
        let e = parse(&format!("{MIN}tolerance_nm = 4\n")).expect_err("an error");
        assert!(e.contains("both tolerance_nm and tolerance_percent"), "{e}");
        let e = parse(&format!(
            "{MIN}[[roi]]\nx = 0\ny = 0\nwidth = 0\nheight = 3\n"
        ))
        .expect_err("an error");
        assert!(e.contains("roi[0]"), "{e}");
        let e = parse(&format!("{MIN}[retention]\nraw = \"some\"\n")).expect_err("an error");
        assert!(e.contains("some") && e.contains("line 9"), "{e}");
        let r = parse(&format!(
            "{MIN}[[roi]]\nx = 30\ny = 0\nwidth = 4\nheight = 3\n"
        ))
        .expect("roi");
        let e = r.check_sensor(32, 24).expect_err("an error").to_string();
        assert!(e.contains("outside the 32 x 24 sensor"), "{e}");
    }
}

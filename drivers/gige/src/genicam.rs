//! GenICam: fetch the device's XML (first/second URL register, `Local:` plain or zipped, see
//! `url`) and evaluate its node map.
//!
//! Node-map evaluation (Integer, Float, Enumeration, Command, Boolean, String, the register
//! nodes, Converter/IntConverter/SwissKnife/IntSwissKnife formulas, selectors, pValue/pMin/pMax
//! indirections, endianness) is done by the `cameleon-genapi` crate; this module adds the
//! transport, URL parsing, unzipping and a small typed facade with clear errors.

use std::panic::AssertUnwindSafe;

use cameleon_genapi::builder::GenApiBuilder;
use cameleon_genapi::prelude::*;
use cameleon_genapi::store::{CacheSink, DefaultNodeStore, DefaultValueStore, NodeStore};
use cameleon_genapi::ValueCtxt;

use crate::client::GvcpClient;
use crate::error::{GigeError, Result};

mod settable;
mod url;
pub use settable::{takes, FeatureState};

pub use url::{fetch_xml, load_xml, xml_text, XmlUrl, MAX_XML_BYTES};

/// Longest formula (`<Formula>`, `<FormulaTo>`, `<FormulaFrom>`, `<Expression>` text, as
/// written in the XML) accepted. Sized from real descriptions (tests/data/genicam-corpus):
/// the longest is Nerian's SceneScan/Scarlet one, 6 243 characters.
pub const MAX_FORMULA_CHARS: usize = 16_384;
/// Deepest parenthesis nesting in a formula; the deepest real one (Euresys Coaxlink) is 54.
pub const MAX_FORMULA_DEPTH: usize = 128;
/// Most operator characters (`+-*/%&|^~<>=?:`, entities counted by their `&`) in a formula:
/// each may add a level to the evaluator's recursion. The most in a real one (Nerian) is 582.
pub const MAX_FORMULA_OPERATORS: usize = 2048;

/// Refuses formulas long or nested enough to drive the node map's recursive formula parser
/// and evaluator past the stack.
fn check_formulas(xml: &str) -> std::result::Result<(), String> {
    for tag in ["Formula", "FormulaTo", "FormulaFrom", "Expression"] {
        let open = format!("<{tag}");
        let close = format!("</{tag}>");
        let mut rest = xml;
        while let Some(i) = rest.find(&open) {
            let after = &rest[i + open.len()..];
            // `<FormulaTo` also starts with `<Formula`: only the exact tag.
            if !after.starts_with(['>', ' ', '\t', '\n', '\r']) {
                rest = after;
                continue;
            }
            let Some(start) = after.find('>') else { break };
            let body = &after[start + 1..];
            let end = body.find(&close).unwrap_or(body.len());
            let formula = &body[..end];
            if formula.len() > MAX_FORMULA_CHARS {
                return Err(format!(
                    "a <{tag}> of {} characters (at most {MAX_FORMULA_CHARS}, 2.6 times the \
                     longest in real cameras' descriptions)",
                    formula.len()
                ));
            }
            let operators = formula
                .chars()
                .filter(|c| "+-*/%&|^~<>=?:".contains(*c))
                .count();
            if operators > MAX_FORMULA_OPERATORS {
                return Err(format!(
                    "a <{tag}> with {operators} operators (at most {MAX_FORMULA_OPERATORS}, 3.5 \
                     times the most in real cameras' descriptions)"
                ));
            }
            let mut depth = 0usize;
            for c in formula.chars() {
                match c {
                    '(' => {
                        depth += 1;
                        if depth > MAX_FORMULA_DEPTH {
                            return Err(format!(
                                "a <{tag}> nests parentheses more than {MAX_FORMULA_DEPTH} deep \
                                 (real cameras' descriptions nest at most 54)"
                            ));
                        }
                    }
                    ')' => depth = depth.saturating_sub(1),
                    _ => {}
                }
            }
            rest = &body[end..];
        }
    }
    Ok(())
}

/// Register access a [`NodeMap`] reads and writes features through: [`GvcpPort`] here, a
/// GenTL producer's port in `handeye-gentl`.
pub use cameleon_genapi::Device as RegisterPort;

/// Register access for the node map over GVCP: 4-byte aligned accesses use READREG/WRITEREG
/// (always supported), others READMEM/WRITEMEM.
#[derive(Debug, Clone)]
pub struct GvcpPort(pub GvcpClient);

impl cameleon_genapi::Device for GvcpPort {
    fn read_mem(
        &mut self,
        address: i64,
        buf: &mut [u8],
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
        let a = u32::try_from(address)?;
        if buf.len() == 4 && a % 4 == 0 {
            buf.copy_from_slice(&self.0.read_reg(a)?.to_be_bytes());
        } else {
            let d = self.0.read_mem(a, buf.len())?;
            buf.copy_from_slice(&d);
        }
        Ok(())
    }

    fn write_mem(
        &mut self,
        address: i64,
        data: &[u8],
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
        let a = u32::try_from(address)?;
        if data.len() == 4 && a % 4 == 0 {
            self.0
                .write_reg(a, u32::from_be_bytes([data[0], data[1], data[2], data[3]]))?;
        } else {
            self.0.write_mem(a, data)?;
        }
        Ok(())
    }
}

/// The GenApi interface of a feature, as [`NodeMap::kind`] reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeatureKind {
    /// IInteger (Integer, IntReg, MaskedIntReg, IntConverter, IntSwissKnife).
    Integer,
    /// IFloat (Float, FloatReg, Converter, SwissKnife).
    Float,
    /// IBoolean.
    Boolean,
    /// IEnumeration.
    Enumeration,
    /// ICommand.
    Command,
    /// IString (String, StringReg).
    String,
    /// Anything else (Category, Register, Port, ...).
    Other,
}

/// A parsed node map (no register cache: every read goes to the device).
pub struct NodeMap {
    store: DefaultNodeStore,
    cx: ValueCtxt<DefaultValueStore, CacheSink>,
    vendor: String,
    model: String,
}

impl std::fmt::Debug for NodeMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NodeMap").finish_non_exhaustive()
    }
}

fn gerr(feature: &str, e: impl std::fmt::Display) -> GigeError {
    GigeError::feature(feature, e.to_string())
}

/// Why a feature that is not readable now cannot be read.
const NOT_READABLE: &str = "is not readable now (not implemented, not available, or write-only)";
/// Why a feature that is not writable now cannot be written.
const NOT_WRITABLE: &str =
    "is not writable now (locked while streaming, not available, or read-only)";

/// `Ok` when the node's access check `r` (`is_readable`, `is_writable`) says the feature may be
/// used now; else the error names the feature and `refusal` ([`NOT_READABLE`],
/// [`NOT_WRITABLE`]).
fn usable(feature: &str, r: cameleon_genapi::GenApiResult<bool>, refusal: &str) -> Result<()> {
    match r {
        Ok(true) => Ok(()),
        Ok(false) => Err(gerr(feature, refusal)),
        Err(e) => Err(gerr(feature, e)),
    }
}

impl NodeMap {
    /// Parse an XML text. Malformed XML is an error (the parser is guarded against panics).
    pub fn from_xml(xml: &str) -> Result<Self> {
        // The XML parser and the node-map builder recurse per element: bound the nesting
        // first (a stack overflow cannot be caught like the panics below).
        handeye_hal::limits::check_xml_nesting(xml, handeye_hal::limits::MAX_XML_DEPTH)
            .map_err(|e| GigeError::malformed("GenICam XML", e))?;
        // So do the formula parser and evaluator (SwissKnife, Converter): bound each formula.
        check_formulas(xml).map_err(|e| GigeError::malformed("GenICam XML", e))?;
        let built = std::panic::catch_unwind(AssertUnwindSafe(|| {
            GenApiBuilder::<
                DefaultNodeStore,
                DefaultValueStore,
                cameleon_genapi::store::DefaultCacheStore,
            >::default()
            .no_cache()
            .build(&xml)
        }));
        match built {
            Ok(Ok((desc, store, cx))) => Ok(Self {
                store,
                cx,
                vendor: desc.vendor_name().to_owned(),
                model: desc.model_name().to_owned(),
            }),
            Ok(Err(e)) => Err(GigeError::malformed("GenICam XML", e.to_string())),
            Err(panic) => {
                let why = panic
                    .downcast_ref::<String>()
                    .map(String::as_str)
                    .or_else(|| panic.downcast_ref::<&str>().copied())
                    .unwrap_or("no detail");
                Err(GigeError::malformed(
                    "GenICam XML",
                    format!("the node map is inconsistent (parser aborted: {why})"),
                ))
            }
        }
    }

    /// The GenApi interface of a feature (`None` when the camera has no such feature).
    pub fn kind(&self, name: &str) -> Option<FeatureKind> {
        let id = self.store.id_by_name(name)?;
        let s = &self.store;
        Some(if id.as_ienumeration_kind(s).is_some() {
            FeatureKind::Enumeration
        } else if id.as_iinteger_kind(s).is_some() {
            FeatureKind::Integer
        } else if id.as_ifloat_kind(s).is_some() {
            FeatureKind::Float
        } else if id.as_iboolean_kind(s).is_some() {
            FeatureKind::Boolean
        } else if id.as_icommand_kind(s).is_some() {
            FeatureKind::Command
        } else if id.as_istring_kind(s).is_some() {
            FeatureKind::String
        } else {
            FeatureKind::Other
        })
    }

    /// Write an on/off feature that cameras declare either as a Boolean or as an Integer
    /// (SFNC's `TLParamsLocked` is an Integer; some Allied Vision cameras make it a Boolean).
    pub fn set_switch(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
        on: bool,
    ) -> Result<()> {
        match self.kind(name) {
            Some(FeatureKind::Boolean) => self.set_boolean(dev, name, on),
            Some(FeatureKind::Integer) => self.set_integer(dev, name, i64::from(on)),
            Some(other) => Err(gerr(
                name,
                format!("is {other:?}, expected a Boolean or an Integer"),
            )),
            None => Err(gerr(name, "the camera has no such feature")),
        }
    }

    /// Takes over a camera a killed capture left streaming: its heartbeat expired and control
    /// came back, but it still streams or keeps its transport parameters locked
    /// (`TLParamsLocked` on, which makes `AcquisitionMode`, the image size and the pixel format
    /// read-only). It is stopped (`AcquisitionStop`) and unlocked before anything is
    /// configured; a camera that is not locked is left alone.
    pub fn take_over(&mut self, dev: &mut impl cameleon_genapi::Device) -> Result<()> {
        let locked = match self.kind("TLParamsLocked") {
            Some(FeatureKind::Boolean) => self.boolean(dev, "TLParamsLocked")?,
            Some(FeatureKind::Integer) => self.integer(dev, "TLParamsLocked")? != 0,
            _ => false,
        };
        if locked {
            tracing::warn!(
                "the camera was left streaming with its transport parameters locked (a capture \
                 that was killed?): stopping it and unlocking them before configuring"
            );
            if self.has("AcquisitionStop") {
                self.execute(dev, "AcquisitionStop")?;
            }
            self.set_switch(dev, "TLParamsLocked", false)?;
        }
        Ok(())
    }

    fn id(&self, name: &str) -> Result<cameleon_genapi::NodeId> {
        self.store
            .id_by_name(name)
            .ok_or_else(|| gerr(name, "the camera has no such feature"))
    }

    /// `VendorName` of the description (its root element).
    pub fn vendor_name(&self) -> &str {
        &self.vendor
    }

    /// `ModelName` of the description (its root element).
    pub fn model_name(&self) -> &str {
        &self.model
    }

    /// Whether the node exists.
    pub fn has(&self, name: &str) -> bool {
        self.store.id_by_name(name).is_some()
    }

    /// Read an integer feature (Integer, IntReg, MaskedIntReg, IntConverter, IntSwissKnife).
    /// Like every read here, refused while the feature is not readable (not implemented, not
    /// available or write-only), as the EMVA reference refuses it.
    pub fn integer(&mut self, dev: &mut impl cameleon_genapi::Device, name: &str) -> Result<i64> {
        let n = self
            .id(name)?
            .expect_iinteger_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_readable(dev, &self.store, &mut self.cx),
            NOT_READABLE,
        )?;
        n.value(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }

    /// Write an integer feature. Like every write here, refused while the feature is not
    /// writable (locked, not available, read-only) or the value is out of its range.
    pub fn set_integer(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
        v: i64,
    ) -> Result<()> {
        let n = self
            .id(name)?
            .expect_iinteger_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_writable(dev, &self.store, &mut self.cx),
            NOT_WRITABLE,
        )?;
        let lo = n
            .min(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))?;
        let hi = n
            .max(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))?;
        if v < lo || v > hi {
            return Err(gerr(name, format!("{v} is outside {lo}..={hi}")));
        }
        n.set_value(v, dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }

    /// Read a float feature (Float, FloatReg, Converter, SwissKnife).
    pub fn float(&mut self, dev: &mut impl cameleon_genapi::Device, name: &str) -> Result<f64> {
        let n = self
            .id(name)?
            .expect_ifloat_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_readable(dev, &self.store, &mut self.cx),
            NOT_READABLE,
        )?;
        n.value(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }

    /// Read an integer or float feature as f64.
    pub fn number(&mut self, dev: &mut impl cameleon_genapi::Device, name: &str) -> Result<f64> {
        let id = self.id(name)?;
        if id.as_iinteger_kind(&self.store).is_some() {
            return self.integer(dev, name).map(|v| v as f64);
        }
        self.float(dev, name)
    }

    /// Write a float feature.
    pub fn set_float(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
        v: f64,
    ) -> Result<()> {
        let n = self
            .id(name)?
            .expect_ifloat_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_writable(dev, &self.store, &mut self.cx),
            NOT_WRITABLE,
        )?;
        let lo = n
            .min(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))?;
        let hi = n
            .max(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))?;
        if !(v >= lo && v <= hi) {
            return Err(gerr(name, format!("{v} is outside {lo}..={hi}")));
        }
        n.set_value(v, dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }

    /// Read a boolean feature.
    pub fn boolean(&mut self, dev: &mut impl cameleon_genapi::Device, name: &str) -> Result<bool> {
        let n = self
            .id(name)?
            .expect_iboolean_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_readable(dev, &self.store, &mut self.cx),
            NOT_READABLE,
        )?;
        n.value(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }

    /// Write a boolean feature.
    pub fn set_boolean(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
        v: bool,
    ) -> Result<()> {
        let n = self
            .id(name)?
            .expect_iboolean_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_writable(dev, &self.store, &mut self.cx),
            NOT_WRITABLE,
        )?;
        n.set_value(v, dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }

    /// Read a string feature.
    pub fn string(&mut self, dev: &mut impl cameleon_genapi::Device, name: &str) -> Result<String> {
        let n = self
            .id(name)?
            .expect_istring_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_readable(dev, &self.store, &mut self.cx),
            NOT_READABLE,
        )?;
        n.value(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }

    /// Current symbolic value of an enumeration.
    pub fn enum_symbol(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
    ) -> Result<String> {
        self.some_entry_implemented(dev, name)?;
        let n = self
            .id(name)?
            .expect_ienumeration_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_readable(dev, &self.store, &mut self.cx),
            NOT_READABLE,
        )?;
        let e = n
            .current_entry(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))?;
        Ok(e.expect_enum_entry(&self.store)
            .map_err(|e| gerr(name, e))?
            .symbolic()
            .to_owned())
    }

    /// Current integer value of an enumeration.
    pub fn enum_value(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
    ) -> Result<i64> {
        self.some_entry_implemented(dev, name)?;
        let n = self
            .id(name)?
            .expect_ienumeration_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_readable(dev, &self.store, &mut self.cx),
            NOT_READABLE,
        )?;
        n.current_value(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }

    /// Select an enumeration entry by symbolic name.
    pub fn set_enum(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
        symbol: &str,
    ) -> Result<()> {
        let n = self
            .id(name)?
            .expect_ienumeration_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        let Some(entry) = n.entry_by_symbolic(symbol, &self.store) else {
            return Err(gerr(
                name,
                format!(
                    "has no entry `{symbol}`; entries: {}",
                    self.enum_entries(name)?.join(", ")
                ),
            ));
        };
        usable(
            name,
            n.is_writable(dev, &self.store, &mut self.cx),
            NOT_WRITABLE,
        )?;
        let e = entry
            .expect_enum_entry(&self.store)
            .map_err(|e| gerr(name, e))?;
        let usable = e
            .is_implemented(dev, &self.store, &mut self.cx)
            .and_then(|i| Ok(i && e.is_available(dev, &self.store, &mut self.cx)?))
            .map_err(|e| gerr(name, e))?;
        if !usable {
            return Err(gerr(
                name,
                format!("`{symbol}` is not available now (not implemented or not available)"),
            ));
        }
        n.set_entry_by_symbolic(symbol, dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }

    /// An enumeration none of whose entries is implemented is itself not implemented (as the
    /// EMVA reference has it: FLIR/Point Grey cameras report their pixel formats so).
    fn some_entry_implemented(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
    ) -> Result<()> {
        let n = self
            .id(name)?
            .expect_ienumeration_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        for id in n.entries(&self.store) {
            let e = id
                .expect_enum_entry(&self.store)
                .map_err(|e| gerr(name, e))?;
            if e.is_implemented(dev, &self.store, &mut self.cx)
                .map_err(|e| gerr(name, e))?
            {
                return Ok(());
            }
        }
        Err(gerr(name, "is not implemented (none of its entries is)"))
    }

    /// Symbolic names and values of all entries of an enumeration.
    pub fn enum_entries(&self, name: &str) -> Result<Vec<String>> {
        Ok(self
            .enum_entries_with_values(name)?
            .into_iter()
            .map(|(s, _)| s)
            .collect())
    }

    /// Symbolic names and integer values of all entries.
    pub fn enum_entries_with_values(&self, name: &str) -> Result<Vec<(String, i64)>> {
        let n = self
            .id(name)?
            .expect_ienumeration_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        let mut out = Vec::new();
        for id in n.entries(&self.store) {
            let e = id
                .expect_enum_entry(&self.store)
                .map_err(|e| gerr(name, e))?;
            out.push((e.symbolic().to_owned(), e.value()));
        }
        Ok(out)
    }

    /// Execute a command feature.
    pub fn execute(&mut self, dev: &mut impl cameleon_genapi::Device, name: &str) -> Result<()> {
        let n = self
            .id(name)?
            .expect_icommand_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_writable(dev, &self.store, &mut self.cx),
            NOT_WRITABLE,
        )?;
        n.execute(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    #[test]
    fn url_forms_parse() {
        assert_eq!(
            XmlUrl::parse("Local:arv-fake-camera.xml;10000;3e67\0\0").expect("url"),
            XmlUrl::Local {
                file: "arv-fake-camera.xml".into(),
                address: 0x10000,
                length: 0x3e67
            }
        );
        assert_eq!(
            XmlUrl::parse("local:///V_M.zip;0xC0000000; 10D4A?SchemaVersion=1.1.0").expect("url"),
            XmlUrl::Local {
                file: "V_M.zip".into(),
                address: 0xC000_0000,
                length: 0x10D4A
            }
        );
        for bad in [
            "",
            "File://camera.local/x.xml",
            "File:///x%2",
            "Local:x;zz;10",
            "Local:x;10",
            "Local:x;10;0",
            "gopher:x",
            "Local:x;100000000;10",
        ] {
            assert!(XmlUrl::parse(bad).is_err(), "{bad}");
        }
    }

    /// Issue 46: `File:` URLs as RFC 8089 says: `File:///abs` and `file://localhost/abs` are
    /// absolute (they were read relative to the working directory, and the failure was called
    /// a network error), a relative path is read from the producer's directory.
    #[test]
    fn issue_46_file_urls_are_absolute_or_relative_to_the_producer() {
        let dir = std::env::temp_dir().join(format!("handeye-file-url-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub dir")).expect("dir");
        let xml = dir.join("sub dir/cam.xml");
        std::fs::write(&xml, "<RegisterDescription/>").expect("xml");
        let abs = xml.display().to_string().replace(' ', "%20");
        let no_mem = |_, _| -> Result<Vec<u8>> { panic!("not a Local: URL") };
        for url in [
            format!("File://{abs}"),
            format!("file://localhost{abs}"),
            format!("File:{abs}?SchemaVersion=1.0.0"),
        ] {
            let parsed = XmlUrl::parse(&url).expect("url");
            assert_eq!(parsed, XmlUrl::File(xml.display().to_string()), "{url}");
            assert_eq!(
                load_xml(parsed, Some(std::path::Path::new("/nonexistent")), no_mem).expect(&url),
                "<RegisterDescription/>"
            );
        }
        let rel = XmlUrl::parse("File:sub%20dir/cam.xml").expect("relative");
        assert_eq!(
            load_xml(rel.clone(), Some(&dir), no_mem).expect("from the producer's dir"),
            "<RegisterDescription/>"
        );
        let e = load_xml(rel, None, no_mem)
            .expect_err("no base")
            .to_string();
        assert!(e.contains("is relative"), "{e}");
        let e = load_xml(
            XmlUrl::parse("File:///nonexistent/x.xml").expect("url"),
            None,
            no_mem,
        )
        .expect_err("missing")
        .to_string();
        assert!(
            e.contains("cannot read the device's XML file /nonexistent/x.xml"),
            "{e}"
        );
        assert!(!e.contains("network"), "{e}");
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }

    #[test]
    fn zipped_and_plain_xml_read_the_same() {
        let xml = "<RegisterDescription/>";
        let mut buf = std::io::Cursor::new(Vec::new());
        {
            let mut w = zip::ZipWriter::new(&mut buf);
            w.start_file("a.xml", zip::write::SimpleFileOptions::default())
                .expect("zip");
            w.write_all(xml.as_bytes()).expect("zip");
            w.finish().expect("zip");
        }
        assert_eq!(xml_text(&buf.into_inner()).expect("zip"), xml);
        assert_eq!(xml_text(b"<a/>\0\0\0").expect("plain"), "<a/>");
        assert!(xml_text(b"PK\x03\x04garbage").is_err());
        assert!(NodeMap::from_xml("<not xml").is_err());
        // Issue 16: a zip bomb (33 MiB of spaces in a few kB) is refused, not truncated.
        let mut buf = std::io::Cursor::new(Vec::new());
        {
            let mut w = zip::ZipWriter::new(&mut buf);
            w.start_file("a.xml", zip::write::SimpleFileOptions::default())
                .expect("zip");
            let chunk = vec![b' '; 1 << 20];
            for _ in 0..33 {
                w.write_all(&chunk).expect("zip");
            }
            w.finish().expect("zip");
        }
        let bomb = buf.into_inner();
        assert!(bomb.len() < 1 << 20, "{} bytes", bomb.len());
        let e = xml_text(&bomb).expect_err("bomb").to_string();
        assert!(e.contains("unzips to more than"), "{e}");
    }

    /// Issue 23 (found by the `genicam-url` fuzz target): a device's URL register with a NUL
    /// inside was echoed raw in the error.
    #[test]
    fn issue_23_xml_url_with_control_characters_is_escaped() {
        let e = XmlUrl::parse("\u{80}\u{0}1")
            .expect_err("no scheme")
            .to_string();
        assert!(e.contains("no scheme"), "{e}");
        assert!(!e.chars().any(char::is_control), "{e:?}");
    }

    /// Fuzz target `genicam-url` (hal::fuzz): mutated XML addresses of the first URL
    /// register parse or are refused with a message.
    #[test]
    fn fuzz_genicam_url() {
        let seeds = [
            "Local:a.xml;10000;3e67",
            "local:///b.zip;0xC0000000;10D4A?x=1",
            "File:/tmp/x.xml",
        ];
        handeye_hal::fuzz::Target::new(
            "genicam-url",
            seeds.iter().map(|s| s.as_bytes().to_vec()).collect(),
        )
        .run(|b| XmlUrl::parse(&String::from_utf8_lossy(b)).map(|_| ()));
    }

    /// Fuzz target `genicam-xml`: mutations of the simulated camera's GenApi XML (the one real
    /// clients load) build a node map or are refused with a message.
    #[test]
    fn fuzz_genicam_xml() {
        let real = include_str!("sim/camera.xml").as_bytes().to_vec();
        handeye_hal::fuzz::Target::new("genicam-xml", vec![real]).run(|b| {
            let text = xml_text(b).map_err(|e| e.to_string())?;
            NodeMap::from_xml(&text)
                .map(|_| ())
                .map_err(|e| e.to_string())
        });
    }

    /// A port over zeroed registers (what the formulas below read).
    struct Zeros;

    impl cameleon_genapi::Device for Zeros {
        fn read_mem(
            &mut self,
            _: i64,
            buf: &mut [u8],
        ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
            buf.fill(0);
            Ok(())
        }

        fn write_mem(
            &mut self,
            _: i64,
            _: &[u8],
        ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
            Ok(())
        }
    }

    /// Issue 35: the formula guards are sized from real descriptions (Nerian's 6 243-character
    /// formula, Euresys' 54-deep nesting); formulas at every limit at once parse and evaluate
    /// on a 2 MiB thread stack (the size of tokio's and the test harness's threads), and one
    /// past a limit is an error naming it.
    #[test]
    fn issue_35_formula_guards_fit_real_files_and_hold_at_their_limits() {
        let real = include_str!("sim/camera.xml");
        let formula = "<Formula>(HIGH &lt;&lt; 32) | LOW</Formula>";
        let depth = MAX_FORMULA_DEPTH - 1;
        // 2 * chain + 2 * depth + 4 characters, chain + 1 operators (each `+`, then `|`).
        let chain = (MAX_FORMULA_OPERATORS - 1).min((MAX_FORMULA_CHARS - 2 * depth - 8) / 2);
        let worst = [
            format!(
                "{}(HIGH{}){}|LOW",
                "(".repeat(depth),
                "+1".repeat(chain),
                ")".repeat(depth)
            ),
            format!("{}LOW", "-".repeat(MAX_FORMULA_OPERATORS)),
        ];
        for (i, f) in worst.iter().enumerate() {
            let xml = real.replace(formula, &format!("<Formula>{f}</Formula>"));
            let value = std::thread::Builder::new()
                .stack_size(2 << 20)
                .spawn(move || {
                    let mut nm = NodeMap::from_xml(&xml).map_err(|e| e.to_string())?;
                    nm.integer(&mut Zeros, "GevTimestampTickFrequency")
                        .map_err(|e| e.to_string())
                })
                .expect("thread")
                .join()
                .expect("no stack overflow");
            assert_eq!(value, Ok(if i == 0 { chain as i64 } else { 0 }), "{i}");
        }
        for (bad, limit) in [
            (
                format!(
                    "{}1{}",
                    "(".repeat(MAX_FORMULA_DEPTH + 1),
                    ")".repeat(MAX_FORMULA_DEPTH + 1)
                ),
                "128 deep",
            ),
            (
                format!("{}1", " ".repeat(MAX_FORMULA_CHARS)),
                "at most 16384",
            ),
            (
                format!("{}LOW", "-".repeat(MAX_FORMULA_OPERATORS + 1)),
                "at most 2048",
            ),
        ] {
            let xml = real.replace(formula, &format!("<Formula>{bad}</Formula>"));
            let e = NodeMap::from_xml(&xml)
                .expect_err("past a limit")
                .to_string();
            assert!(e.contains(limit), "{e}");
        }
    }

    /// Issue 35: legal GenApi that cameleon-genapi 0.1.14 aborted on (patched in
    /// vendor/cameleon-genapi): float literals with an exponent, `ROUND(x, n)`, empty
    /// elements, values padded with whitespace.
    #[test]
    fn issue_35_vendor_forms_load_and_evaluate() {
        let real = include_str!("sim/camera.xml");
        let formula = "<Formula>(HIGH &lt;&lt; 32) | LOW</Formula>";
        for (f, want) in [
            ("(LOW&lt;&gt;0)?(1e6/LOW):(2.5E3*2)", 5000),
            ("ROUND(1234.5678 * 10, 0) + ROUND(0.25, 1)", 12346),
            ("SGN(LOW - 3) * 7", -7),
        ] {
            let xml = real.replace(formula, &format!("<Formula>{f}</Formula>"));
            let mut nm = NodeMap::from_xml(&xml).unwrap_or_else(|e| panic!("{f}: {e}"));
            assert_eq!(
                nm.integer(&mut Zeros, "GevTimestampTickFrequency")
                    .expect(f),
                want,
                "{f}"
            );
        }
        // `<Visibility>\n Beginner\n</Visibility>`, `<Streamable/>`.
        let padded = real
            .replacen(
                "<Visibility>Invisible</Visibility>",
                "<Visibility>\n    Invisible\n  </Visibility><Streamable/>",
                1,
            )
            .replace("<Min>16</Min>", "<Min>\n 16 \n</Min>");
        assert_ne!(padded, real);
        let mut nm = NodeMap::from_xml(&padded).expect("padded values load");
        assert!(nm.has("TLParamsLocked"));
        assert!(
            nm.set_integer(&mut Zeros, "Width", 15).is_err(),
            "Min 16 still holds"
        );
    }

    /// Issue 16: a device's XML nested tens of thousands of elements deep is an error, not a
    /// stack overflow; structure-aware cases around the limit, huge repetition counts and huge
    /// numbers through the node-map builder.
    #[test]
    fn issue_16_deep_and_huge_genicam_xml_are_errors() {
        use rand::{Rng, SeedableRng};
        let n = 50_000;
        for tag in ["Category", "pFeature", "x"] {
            let xml = format!(
                r#"<?xml version="1.0"?><RegisterDescription ModelName="m" VendorName="v" StandardNameSpace="None" SchemaMajorVersion="1" SchemaMinorVersion="1" SchemaSubMinorVersion="0" MajorVersion="1" MinorVersion="0" SubMinorVersion="0" ProductGuid="0" VersionGuid="0" xmlns="http://www.genicam.org/GenApi/Version_1_1">{}{}</RegisterDescription>"#,
                format!("<{tag}>").repeat(n),
                format!("</{tag}>").repeat(n)
            );
            let e = NodeMap::from_xml(&xml).expect_err("too deep").to_string();
            assert!(e.contains("nested more than"), "{e}");
        }
        let real = include_str!("sim/camera.xml");
        NodeMap::from_xml(real).expect("the simulated camera's XML loads");
        // Formulas: deep parentheses, a huge chain of operators.
        let formula = "<Formula>(HIGH &lt;&lt; 32) | LOW</Formula>";
        assert!(real.contains(formula));
        for bad in [
            format!("{}1{}", "(".repeat(100_000), ")".repeat(100_000)),
            "1+".repeat(500_000) + "1",
            "-".repeat(1_000_000) + "1",
        ] {
            let xml = real.replace(formula, &format!("<Formula>{bad}</Formula>"));
            let e = NodeMap::from_xml(&xml)
                .expect_err("hostile formula")
                .to_string();
            assert!(e.contains("<Formula>"), "{e}");
        }
        let mut rng = rand::rngs::StdRng::seed_from_u64(16);
        let numbers = [
            "18446744073709551616",
            "-9223372036854775809",
            "1e308",
            "0x",
            "nan",
        ];
        for _ in 0..20 {
            let at = real.find("</RegisterDescription>").expect("root end");
            let depth = rng.random_range(1..300);
            let reps = rng.random_range(0..500);
            let num = numbers[rng.random_range(0..numbers.len())];
            let extra = format!(
                "{}{}{}",
                "<Category Name=\"C\"><pFeature>".repeat(depth),
                format!("<Integer Name=\"I\"><Value>{num}</Value></Integer>").repeat(reps),
                "</pFeature></Category>".repeat(depth),
            );
            let xml = format!("{}{extra}{}", &real[..at], &real[at..]);
            let _ = NodeMap::from_xml(&xml);
        }
    }
}

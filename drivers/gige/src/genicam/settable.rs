//! Features a user sets from the configuration (`[camera.features]`, `camera.user_set`), and
//! what `handeye camera probe` shows of them: the value, the range or entries, the access.

use handeye_hal::FeatureValue;

use super::{gerr, usable, FeatureKind, NodeMap, NOT_WRITABLE};
use crate::error::Result;
use cameleon_genapi::prelude::*;
use cameleon_genapi::store::NodeStore;

/// What a feature is and allows now (`handeye camera probe`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FeatureState {
    /// The feature's name.
    pub name: String,
    /// Its GenApi interface (`Enumeration`, `Float`, …).
    pub kind: String,
    /// Its value now (`None` when it cannot be read now).
    pub value: Option<String>,
    /// What it accepts: `min..=max` (with the unit the description gives) or the entries
    /// available now; `None` for booleans, strings and commands.
    pub allowed: Option<String>,
    /// `read/write`, `read-only`, `write-only` or `not available` (now: a feature locked while
    /// streaming or behind a selector may change).
    pub access: String,
}

/// A float as people read it: `1e308` rather than 309 digits, `0.25` as is.
fn short(x: f64) -> String {
    let a = x.abs();
    if a != 0.0 && !(1e-4..1e9).contains(&a) {
        format!("{x:e}")
    } else {
        x.to_string()
    }
}

impl NodeMap {
    /// Whether the feature is readable and writable now (both false for one the camera lacks,
    /// or whose access cannot be evaluated).
    fn access(&mut self, dev: &mut impl cameleon_genapi::Device, name: &str) -> (bool, bool) {
        let Some(id) = self.store.id_by_name(name) else {
            return (false, false);
        };
        let (s, cx) = (&self.store, &mut self.cx);
        macro_rules! rw {
            ($n:expr) => {
                (
                    $n.is_readable(dev, s, cx).unwrap_or(false),
                    $n.is_writable(dev, s, cx).unwrap_or(false),
                )
            };
        }
        if let Some(n) = id.as_ienumeration_kind(s) {
            rw!(n)
        } else if let Some(n) = id.as_iinteger_kind(s) {
            rw!(n)
        } else if let Some(n) = id.as_ifloat_kind(s) {
            rw!(n)
        } else if let Some(n) = id.as_iboolean_kind(s) {
            rw!(n)
        } else if let Some(n) = id.as_istring_kind(s) {
            rw!(n)
        } else if let Some(n) = id.as_icommand_kind(s) {
            (false, n.is_writable(dev, s, cx).unwrap_or(false))
        } else {
            (false, false)
        }
    }

    /// The entries of an enumeration that are implemented and available now.
    pub fn available_entries(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
    ) -> Result<Vec<String>> {
        let n = self
            .id(name)?
            .expect_ienumeration_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        let mut out = Vec::new();
        for id in n.entries(&self.store) {
            let e = id
                .expect_enum_entry(&self.store)
                .map_err(|e| gerr(name, e))?;
            let here = e
                .is_implemented(dev, &self.store, &mut self.cx)
                .and_then(|i| Ok(i && e.is_available(dev, &self.store, &mut self.cx)?))
                .unwrap_or(false);
            if here {
                out.push(e.symbolic().to_owned());
            }
        }
        Ok(out)
    }

    /// What the feature accepts now: `min..=max unit` for numbers, the available entries of an
    /// enumeration; `None` for other kinds or when the camera lacks it.
    pub fn allowed(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
    ) -> Option<String> {
        let id = self.store.id_by_name(name)?;
        let (s, cx) = (&self.store, &mut self.cx);
        let unit = |u: Option<&str>| u.filter(|u| !u.is_empty()).map(|u| format!(" {u}"));
        if id.as_ienumeration_kind(s).is_some() {
            return self
                .available_entries(dev, name)
                .ok()
                .map(|e| format!("one of {}", e.join(", ")));
        }
        if let Some(n) = id.as_iinteger_kind(s) {
            let lo = n.min(dev, s, cx).ok()?;
            let hi = n.max(dev, s, cx).ok()?;
            let u = unit(n.unit(s)).unwrap_or_default();
            return Some(match n.inc(dev, s, cx) {
                Ok(Some(inc)) if inc > 1 => format!("{lo}..={hi}{u}, in steps of {inc}"),
                _ => format!("{lo}..={hi}{u}"),
            });
        }
        if let Some(n) = id.as_ifloat_kind(s) {
            let lo = n.min(dev, s, cx).ok()?;
            let hi = n.max(dev, s, cx).ok()?;
            return Some(format!(
                "{}..={}{}",
                short(lo),
                short(hi),
                unit(n.unit(s)).unwrap_or_default()
            ));
        }
        None
    }

    /// The feature's value now as text (`None` when it cannot be read now).
    fn value_text(&mut self, dev: &mut impl cameleon_genapi::Device, name: &str) -> Option<String> {
        match self.kind(name)? {
            FeatureKind::Integer => self.integer(dev, name).ok().map(|v| v.to_string()),
            FeatureKind::Float => self.float(dev, name).ok().map(short),
            FeatureKind::Boolean => self.boolean(dev, name).ok().map(|v| v.to_string()),
            FeatureKind::Enumeration => self.enum_symbol(dev, name).ok(),
            FeatureKind::String => self.string(dev, name).ok(),
            FeatureKind::Command | FeatureKind::Other => None,
        }
    }

    /// The feature's kind, value, what it accepts and its access now; `None` when the camera
    /// lacks it.
    pub fn state(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
    ) -> Option<FeatureState> {
        let kind = self.kind(name)?;
        let (r, w) = self.access(dev, name);
        let value = if r { self.value_text(dev, name) } else { None };
        Some(FeatureState {
            name: name.to_owned(),
            kind: format!("{kind:?}"),
            value,
            allowed: self.allowed(dev, name),
            access: match (r, w) {
                (true, true) => "read/write",
                (true, false) => "read-only",
                (false, true) => "write-only",
                (false, false) => "not available",
            }
            .into(),
        })
    }

    /// Write a string feature (String, StringReg), refused while not writable or longer than
    /// its maximum length.
    pub fn set_string(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
        v: &str,
    ) -> Result<()> {
        let n = self
            .id(name)?
            .expect_istring_kind(&self.store)
            .map_err(|e| gerr(name, e))?;
        usable(
            name,
            n.is_writable(dev, &self.store, &mut self.cx),
            NOT_WRITABLE,
        )?;
        let max = n
            .max_length(dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))?;
        if v.len() as i64 > max {
            return Err(gerr(
                name,
                format!("`{v}` is {} bytes, longer than its {max}", v.len()),
            ));
        }
        n.set_value(v.to_owned(), dev, &self.store, &mut self.cx)
            .map_err(|e| gerr(name, e))
    }

    /// Write `value` to the feature `name` by the feature's own interface: an entry's name to an
    /// enumeration, a whole number to an integer, a number to a float, `true`/`false` to a
    /// boolean, text to a string; `true` executes a command. The ranges and access checks of
    /// the setters apply; a value of the wrong kind is refused with what the feature accepts.
    pub fn write_value(
        &mut self,
        dev: &mut impl cameleon_genapi::Device,
        name: &str,
        value: &FeatureValue,
    ) -> Result<()> {
        use FeatureValue as V;
        let Some(kind) = self.kind(name) else {
            return Err(gerr(name, "the camera has no such feature"));
        };
        if let Err(wants) = takes(kind, value) {
            let allowed = self
                .allowed(dev, name)
                .map(|a| format!(" ({a})"))
                .unwrap_or_default();
            return Err(gerr(
                name,
                format!("is {kind:?} and takes {wants}{allowed}, not {value}"),
            ));
        }
        match (kind, value) {
            (FeatureKind::Enumeration, V::Text(t)) => self.set_enum(dev, name, t),
            (FeatureKind::Integer, V::Int(i)) => self.set_integer(dev, name, *i),
            (FeatureKind::Float, V::Int(i)) => self.set_float(dev, name, *i as f64),
            (FeatureKind::Float, V::Float(x)) => self.set_float(dev, name, *x),
            (FeatureKind::Boolean, V::Bool(b)) => self.set_boolean(dev, name, *b),
            (FeatureKind::String, V::Text(t)) => self.set_string(dev, name, t),
            _ => self.execute(dev, name),
        }
    }
}

/// `Ok` when a feature of `kind` takes `value` (an entry's name for an enumeration, a whole
/// number for an integer, a number for a float, true/false for a boolean, text for a string,
/// `true` to execute a command); else what it takes.
pub fn takes(kind: FeatureKind, value: &FeatureValue) -> std::result::Result<(), &'static str> {
    use FeatureValue as V;
    match (kind, value) {
        (FeatureKind::Enumeration | FeatureKind::String, V::Text(_))
        | (FeatureKind::Integer, V::Int(_))
        | (FeatureKind::Float, V::Int(_) | V::Float(_))
        | (FeatureKind::Boolean, V::Bool(_))
        | (FeatureKind::Command, V::Bool(true)) => Ok(()),
        (FeatureKind::Enumeration, _) => Err("an entry's name in quotes"),
        (FeatureKind::Integer, _) => Err("a whole number"),
        (FeatureKind::Float, _) => Err("a number"),
        (FeatureKind::Boolean, _) => Err("true or false"),
        (FeatureKind::String, _) => Err("text in quotes"),
        (FeatureKind::Command, _) => Err("true (to execute it)"),
        (FeatureKind::Other, _) => Err("nothing: it is not a value"),
    }
}

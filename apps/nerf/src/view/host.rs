//! The viewer's guard against DNS rebinding: a request is answered only when its `Host` names
//! the viewer by an address or name the user chose, so a page on another site whose name has
//! been pointed at this machine (its requests carry that site's name) cannot read frames.
//!
//! * Bound to loopback: `127.0.0.1`, `localhost` and `[::1]` (and the bound address itself).
//! * Bound to one other address: that address, and the name given with `--host` if it was a
//!   name.
//! * Bound to every address (`0.0.0.0`, `::`): any IP address (an address typed into the
//!   browser cannot be rebound: rebinding needs a name), `localhost`, and the `--host` name.
//!
//! Any port is accepted with these (an `ssh -L` tunnel forwards from another port). A request
//! without `Host` is a 400, one with another host a 403, each with a one-line reason.

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr};

/// The `Host` values the viewer answers.
#[derive(Debug, Clone, PartialEq)]
pub struct AllowedHosts {
    bound: IpAddr,
    /// The `--host` value when it is a name rather than an address, lower case.
    name: Option<String>,
}

/// Why a request's host was refused.
#[derive(Debug, Clone, PartialEq)]
pub enum HostRefusal {
    /// No `Host` header (HTTP/1.1 requires one): a 400.
    Missing,
    /// Another host, or a malformed value: a 403 with this reason.
    Foreign(String),
}

/// Splits a `Host` value into host and port; `None` when malformed. IPv6 addresses keep no
/// brackets; names are lower-cased.
fn split_host(value: &str) -> Option<(String, Option<u16>)> {
    let (host, port) = if let Some(rest) = value.strip_prefix('[') {
        let (inside, after) = rest.split_once(']')?;
        inside.parse::<Ipv6Addr>().ok()?;
        let port = match after {
            "" => None,
            p => Some(p.strip_prefix(':')?),
        };
        (inside, port)
    } else {
        match value.split_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (value, None),
        }
    };
    let port = match port {
        None => None,
        Some(p) if !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()) => Some(p.parse().ok()?),
        Some(_) => return None,
    };
    let ok = |b: u8| b.is_ascii_alphanumeric() || b"-._:".contains(&b);
    if host.is_empty() || !host.bytes().all(ok) {
        return None;
    }
    Some((host.to_ascii_lowercase(), port))
}

impl AllowedHosts {
    /// The hosts for a viewer bound to `bound`, asked for with `--host bind_host`.
    pub fn new(bind_host: &str, bound: IpAddr) -> Self {
        let bare = bind_host.trim_start_matches('[').trim_end_matches(']');
        let name = bare
            .parse::<IpAddr>()
            .is_err()
            .then(|| bare.to_ascii_lowercase());
        Self { bound, name }
    }

    /// What is accepted, for the refusal message.
    fn expected(&self) -> String {
        let mut names: Vec<String> = if self.bound.is_loopback() {
            vec!["127.0.0.1".into(), "localhost".into(), "[::1]".into()]
        } else if self.bound.is_unspecified() {
            vec!["an IP address".into(), "localhost".into()]
        } else {
            vec![]
        };
        let bound = match self.bound {
            IpAddr::V6(v6) => format!("[{v6}]"),
            v4 => v4.to_string(),
        };
        if !self.bound.is_unspecified() && !names.contains(&bound) {
            names.push(bound);
        }
        if let Some(name) = &self.name {
            if !names.contains(name) {
                names.push(name.clone());
            }
        }
        names.join(", ")
    }

    fn accepts(&self, host: &str) -> bool {
        if self.name.as_deref() == Some(host) {
            return true;
        }
        let loopback = self.bound.is_loopback();
        match host.parse::<IpAddr>() {
            Ok(_) if self.bound.is_unspecified() => true,
            Ok(ip) if loopback => {
                ip == self.bound
                    || ip == IpAddr::V4(Ipv4Addr::LOCALHOST)
                    || ip == IpAddr::V6(Ipv6Addr::LOCALHOST)
            }
            Ok(ip) => ip == self.bound,
            Err(_) => host == "localhost" && (loopback || self.bound.is_unspecified()),
        }
    }

    /// Checks a request's `Host` header (its raw bytes, if any).
    pub fn check(&self, host: Option<&[u8]>) -> Result<(), HostRefusal> {
        let Some(raw) = host else {
            return Err(HostRefusal::Missing);
        };
        let shown = String::from_utf8_lossy(raw);
        let refuse = || {
            HostRefusal::Foreign(format!(
                "Host {:?} is not this viewer's address (it answers {}; a guard against DNS rebinding)",
                shown.chars().take(100).collect::<String>(),
                self.expected()
            ))
        };
        let value = std::str::from_utf8(raw).map_err(|_| refuse())?;
        let (name, _port) = split_host(value.trim()).ok_or_else(refuse)?;
        if self.accepts(&name) {
            Ok(())
        } else {
            Err(refuse())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(hosts: &AllowedHosts, value: &str) -> bool {
        hosts.check(Some(value.as_bytes())).is_ok()
    }

    #[test]
    fn loopback_answers_loopback_names_only() {
        let h = AllowedHosts::new("127.0.0.1", "127.0.0.1".parse().unwrap());
        for ok in [
            "127.0.0.1:7007",
            "127.0.0.1",
            "localhost:7007",
            "LocalHost",
            "[::1]:8080",
            "[::1]",
        ] {
            assert!(check(&h, ok), "{ok}");
        }
        for bad in [
            "evil.example:7007",
            "evil.example",
            "localhost.evil.example",
            "127.0.0.2:7007",
            "10.0.0.1",
            "[::2]:1",
            "localhost:",
            "localhost:x",
            "localhost:99999",
            "127.0.0.1:7007:1",
            "[::1",
            "[::1]x",
            "a@localhost",
            "",
            " ",
        ] {
            assert!(!check(&h, bad), "{bad:?}");
        }
        let err = h.check(Some(b"evil.example")).unwrap_err();
        let HostRefusal::Foreign(message) = err else {
            panic!("{err:?}")
        };
        assert!(message.contains("127.0.0.1, localhost, [::1]"), "{message}");
        assert!(!check(&h, "\u{e9}vil"));
        assert!(h.check(Some(&[0xff, 0x41])).is_err());
        assert_eq!(h.check(None), Err(HostRefusal::Missing));
        // `--host localhost` binds 127.0.0.1 (or ::1): the same names.
        let h = AllowedHosts::new("localhost", "::1".parse().unwrap());
        assert!(check(&h, "localhost:1") && check(&h, "[::1]:1") && check(&h, "127.0.0.1"));
        assert!(!check(&h, "evil.example"));
    }

    #[test]
    fn another_address_answers_itself_and_the_name_given() {
        let h = AllowedHosts::new("viewer.lan", "192.168.1.5".parse().unwrap());
        for ok in ["192.168.1.5:7007", "viewer.lan:7007", "VIEWER.LAN"] {
            assert!(check(&h, ok), "{ok}");
        }
        for bad in ["localhost", "127.0.0.1", "192.168.1.6", "evil.example"] {
            assert!(!check(&h, bad), "{bad}");
        }
        let h = AllowedHosts::new("192.168.1.5", "192.168.1.5".parse().unwrap());
        assert!(check(&h, "192.168.1.5") && !check(&h, "viewer.lan"));
        let h = AllowedHosts::new("fe80::1", "fe80::1".parse().unwrap());
        assert!(check(&h, "[fe80::1]:7007") && !check(&h, "[fe80::2]:7007"));
    }

    #[test]
    fn every_address_answers_addresses_and_localhost_not_other_names() {
        let h = AllowedHosts::new("0.0.0.0", "0.0.0.0".parse().unwrap());
        for ok in ["10.1.2.3:7007", "127.0.0.1", "[::1]:1", "localhost"] {
            assert!(check(&h, ok), "{ok}");
        }
        for bad in ["evil.example", "myhost"] {
            assert!(!check(&h, bad), "{bad}");
        }
    }
}

//! Which `Host` and `Origin` values name this server: the configuration behind the
//! cross-site checks in `auth.rs` (DNS rebinding, cross-origin posts).

/// Which `Host` and `Origin` values name this server.
#[derive(Debug, Default)]
pub struct OriginPolicy {
    /// Host names besides IP literals and loopback names, lowercase (`--allowed-host`).
    names: Vec<String>,
}

impl OriginPolicy {
    #[must_use]
    pub fn new(allowed: &[String]) -> Self {
        Self {
            names: allowed
                .iter()
                .map(|n| n.trim().to_ascii_lowercase())
                .collect(),
        }
    }

    /// Whether a `Host` value (`name[:port]`) may name this server. An IP literal always
    /// may: DNS rebinding needs a name the attacker controls. So may `localhost` and its
    /// subdomains (RFC 6761 §6.3: they resolve to loopback) and the configured names.
    /// The port is not compared: a rebound name reaches the same port.
    #[must_use]
    pub fn allows_host(&self, host: &str) -> bool {
        let name = host_name(host).to_ascii_lowercase();
        name.parse::<std::net::IpAddr>().is_ok()
            || name == "localhost"
            || name.ends_with(".localhost")
            || self.names.contains(&name)
    }

    /// Whether an `Origin` value is this server as the request's `Host` names it, or a
    /// configured name (a page served by a proxy under that name).
    #[must_use]
    pub fn allows_origin(&self, origin: &str, host: Option<&str>) -> bool {
        let Some(authority) = origin
            .strip_prefix("http://")
            .or_else(|| origin.strip_prefix("https://"))
        else {
            return false; // "null" (sandboxed pages, files) and other schemes
        };
        host.is_some_and(|h| h.eq_ignore_ascii_case(authority))
            || self
                .names
                .iter()
                .any(|n| n.eq_ignore_ascii_case(host_name(authority)))
    }
}

/// The name of a `host[:port]` authority (an IPv6 literal keeps no brackets).
fn host_name(authority: &str) -> &str {
    if let Some(rest) = authority.strip_prefix('[') {
        return rest.split(']').next().unwrap_or(rest);
    }
    authority.rsplit_once(':').map_or(authority, |(h, _)| h)
}

//! Browser sessions: a random id in the `tessera_session` cookie, mapped here to the
//! principal whose token logged in, for 12 hours.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use tessera_coordinator::Principal;

/// Name of the session cookie.
pub(crate) const COOKIE: &str = "tessera_session";
/// How long a session lives.
pub(crate) const LIFETIME: Duration = Duration::from_secs(12 * 3600);
/// The most sessions held: logins beyond it are refused (each costs ~100 bytes, but a
/// stream of logins must not grow the map without bound).
pub(crate) const MAX_SESSIONS: usize = 10_000;

#[derive(Default)]
pub(crate) struct Sessions {
    map: Mutex<HashMap<String, (Principal, Instant)>>,
}

/// Why a session could not be opened.
#[derive(Debug, thiserror::Error)]
pub(crate) enum SessionError {
    #[error("{MAX_SESSIONS} sessions are open; try again later")]
    Full,
    #[error("the system's random source failed: {0}")]
    Random(String),
}

impl Sessions {
    fn map(&self) -> std::sync::MutexGuard<'_, HashMap<String, (Principal, Instant)>> {
        self.map.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A new session of `who`: its id.
    pub(crate) fn open(&self, who: Principal) -> Result<String, SessionError> {
        let mut bytes = [0u8; 32];
        getrandom::fill(&mut bytes).map_err(|e| SessionError::Random(e.to_string()))?;
        let id: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        let now = Instant::now();
        let mut map = self.map();
        map.retain(|_, (_, expires)| *expires > now);
        if map.len() >= MAX_SESSIONS {
            return Err(SessionError::Full);
        }
        map.insert(id.clone(), (who, now + LIFETIME));
        Ok(id)
    }

    /// The principal of session `id`, while it lives.
    pub(crate) fn get(&self, id: &str) -> Option<Principal> {
        let mut map = self.map();
        match map.get(id) {
            Some((p, expires)) if *expires > Instant::now() => Some(p.clone()),
            Some(_) => {
                map.remove(id);
                None
            }
            None => None,
        }
    }

    /// Ends session `id`.
    pub(crate) fn close(&self, id: &str) {
        self.map().remove(id);
    }
}

/// The session id in a `Cookie` header, if any.
pub(crate) fn from_cookie_header(header: &str) -> Option<&str> {
    header.split(';').filter_map(|kv| kv.trim().split_once('=')).find(|(k, _)| *k == COOKIE).map(|(_, v)| v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_coordinator::Role;

    #[test]
    fn sessions_open_resolve_and_close() {
        let s = Sessions::default();
        let alice = Principal { role: Role::Submitter, name: "alice".into() };
        let id = s.open(alice.clone()).unwrap();
        assert_eq!(id.len(), 64);
        assert_eq!(s.get(&id), Some(alice));
        assert_eq!(s.get("nope"), None);
        s.close(&id);
        assert_eq!(s.get(&id), None);
    }

    #[test]
    fn the_cookie_is_found_among_others() {
        assert_eq!(from_cookie_header("a=1; tessera_session=abc; b=2"), Some("abc"));
        assert_eq!(from_cookie_header("tessera_session=x"), Some("x"));
        assert_eq!(from_cookie_header("other=1"), None);
    }
}

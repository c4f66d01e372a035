//! Browser sessions: a random id in the `tessera_session` cookie, mapped here to the
//! principal whose token logged in, for 12 hours. The map is bounded per principal and
//! in all; a full map drops its oldest session rather than refuse logins, so that logging
//! in many times locks nobody else out.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use tessera_coordinator::Principal;

/// Name of the session cookie.
pub(crate) const COOKIE: &str = "tessera_session";
/// How long a session lives.
pub(crate) const LIFETIME: Duration = Duration::from_secs(12 * 3600);
/// The most sessions held in all (each costs ~100 bytes, but a stream of logins must not
/// grow the map without bound); a login beyond it drops the oldest session.
pub(crate) const MAX_SESSIONS: usize = 10_000;
/// The most sessions of one principal (its browsers); a login beyond it drops that
/// principal's oldest session.
pub(crate) const MAX_PER_PRINCIPAL: usize = 16;

/// Session id -> (principal, expiry, login number: the order of logins, which equal
/// `Instant`s could not tell).
type Map = HashMap<String, (Principal, Instant, u64)>;

#[derive(Default)]
pub(crate) struct Sessions {
    map: Mutex<Map>,
    logins: std::sync::atomic::AtomicU64,
}

/// Why a session could not be opened.
#[derive(Debug, thiserror::Error)]
pub(crate) enum SessionError {
    #[error("the system's random source failed: {0}")]
    Random(String),
}

/// Removes the session of `map` opened first among those `which` picks.
fn drop_oldest(map: &mut Map, which: impl Fn(&Principal) -> bool) {
    let oldest = map
        .iter()
        .filter(|(_, (p, _, _))| which(p))
        .min_by_key(|(_, (_, _, n))| *n)
        .map(|(id, _)| id.clone());
    if let Some(id) = oldest {
        map.remove(&id);
    }
}

impl Sessions {
    fn map(&self) -> std::sync::MutexGuard<'_, Map> {
        self.map.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A new session of `who`: its id.
    pub(crate) fn open(&self, who: Principal) -> Result<String, SessionError> {
        self.open_within(who, MAX_SESSIONS)
    }

    fn open_within(&self, who: Principal, max_sessions: usize) -> Result<String, SessionError> {
        let mut bytes = [0u8; 32];
        getrandom::fill(&mut bytes).map_err(|e| SessionError::Random(e.to_string()))?;
        let id: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        let now = Instant::now();
        let mut map = self.map();
        map.retain(|_, (_, expires, _)| *expires > now);
        while map.values().filter(|(p, _, _)| *p == who).count() >= MAX_PER_PRINCIPAL {
            drop_oldest(&mut map, |p| *p == who);
        }
        while map.len() >= max_sessions.max(1) {
            drop_oldest(&mut map, |_| true);
        }
        let n = self.logins.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        map.insert(id.clone(), (who, now + LIFETIME, n));
        Ok(id)
    }

    /// How many sessions are held (expired ones included until the next login).
    #[cfg(test)]
    fn len(&self) -> usize {
        self.map().len()
    }

    /// The principal of session `id`, while it lives.
    pub(crate) fn get(&self, id: &str) -> Option<Principal> {
        let mut map = self.map();
        match map.get(id) {
            Some((p, expires, _)) if *expires > Instant::now() => Some(p.clone()),
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

    /// One principal's 17th login drops its first session and nobody else's; a full map
    /// drops its oldest session instead of refusing the login.
    #[test]
    fn sessions_are_capped_per_principal_and_in_all() {
        let s = Sessions::default();
        let admin = Principal { role: Role::Admin, name: "root".into() };
        let alice = Principal { role: Role::Submitter, name: "alice".into() };
        let admins = s.open(admin.clone()).unwrap();
        let first = s.open(alice.clone()).unwrap();
        let mut ids = vec![first.clone()];
        for _ in 1..MAX_PER_PRINCIPAL {
            ids.push(s.open(alice.clone()).unwrap());
        }
        assert!(ids.iter().all(|id| s.get(id).is_some()));
        let newest = s.open(alice.clone()).unwrap();
        assert_eq!(s.get(&first), None);
        assert!(ids[1..].iter().all(|id| s.get(id) == Some(alice.clone())));
        assert_eq!(s.get(&newest), Some(alice.clone()));
        assert_eq!(s.get(&admins), Some(admin.clone()));
        assert_eq!(s.len(), 1 + MAX_PER_PRINCIPAL);

        // In all: with room for 3, a fourth login (of anyone) drops the oldest.
        let s = Sessions::default();
        let a = s.open_within(admin.clone(), 3).unwrap();
        let b = s.open_within(alice.clone(), 3).unwrap();
        let c = s.open_within(alice.clone(), 3).unwrap();
        let d = s.open_within(admin.clone(), 3).unwrap();
        assert_eq!((s.get(&a), s.len()), (None, 3));
        for id in [&b, &c, &d] {
            assert!(s.get(id).is_some());
        }
    }

    #[test]
    fn the_cookie_is_found_among_others() {
        assert_eq!(from_cookie_header("a=1; tessera_session=abc; b=2"), Some("abc"));
        assert_eq!(from_cookie_header("tessera_session=x"), Some("x"));
        assert_eq!(from_cookie_header("other=1"), None);
    }
}

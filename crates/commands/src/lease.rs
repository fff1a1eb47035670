//! The control lease as the command path checks it: who may command the bus right now.
//!
//! The policy (acquire, keep-alive, take-over, release, what a lapse does) lives in the node's
//! Python code (`ether_ros.ros.lease`); this is the state it decides, in a form every command
//! entry point can read without a lock and without the GIL: the native command threads for
//! each message they take, Python for each service call. One writer at a time (Python, behind
//! `writer`) publishes a new state under a sequence counter (odd while it writes); a reader
//! copies the state and retries if the counter moved, so it never waits for the writer and the
//! writer never waits for a reader. No real-time thread reads it.
//!
//! A request is identified either by the publisher GID the middleware reports for a message
//! (`rmw_message_info_t.publisher_gid`: which DataWriter sent it) or by the lease token a
//! service request carries (`lease` field of the project's services). The holder's GIDs are
//! those of its publishers on the command topics, registered when it acquires or renews.
//!
//! The refusal texts are written here once and used by every path (native and Python), so a
//! client sees the same words wherever its request was refused.

use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, AtomicU8, AtomicUsize, Ordering};
use std::sync::Mutex;

/// Size of a publisher GID (`RMW_GID_STORAGE_SIZE` in ROS 2 Jazzy).
pub const GID_LEN: usize = 16;
/// Publishers one holder may register (its command topics, a few nodes of its own).
pub const MAX_WRITERS: usize = 32;
/// Longest holder name kept (longer names are cut at a character boundary).
pub const HOLDER_LEN: usize = 128;

/// A publisher's global id as rmw reports it: what the lease compares to know who sent.
pub type Gid = [u8; GID_LEN];

/// Whether a request may command the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// The lease is off, or the request comes from the holder.
    Allowed,
    /// Nobody holds the lease.
    NoHolder,
    /// Someone else holds it.
    HeldByOther,
    /// The holder's lease ran out (nobody holds it now).
    Lapsed,
}

/// The lease state at one instant (a consistent copy).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LeaseState {
    /// Whether the lease is checked at all (off: every publisher may command).
    pub enabled: bool,
    /// CLOCK_MONOTONIC ns the lease runs out (0: nobody holds it).
    pub expires_ns: i64,
    /// Increases with every grant, so a stale renewal cannot extend a newer lease.
    pub token: u64,
    /// Who holds the lease, as the holder named itself (for messages and the status topic).
    pub holder: String,
    /// The holder's publishers: messages from these gids pass the lease check.
    pub gids: Vec<Gid>,
}

/// The lock-free lease state (see the module doc).
pub struct LeaseGate {
    seq: AtomicU64,
    enabled: AtomicBool,
    expires_ns: AtomicI64,
    token: AtomicU64,
    holder_len: AtomicUsize,
    holder: [AtomicU8; HOLDER_LEN],
    count: AtomicUsize,
    gids: [[AtomicU64; 2]; MAX_WRITERS],
    /// Serializes writers (Python threads); readers never take it.
    writer: Mutex<()>,
}

impl Default for LeaseGate {
    fn default() -> Self {
        LeaseGate {
            seq: AtomicU64::new(0),
            enabled: AtomicBool::new(false),
            expires_ns: AtomicI64::new(0),
            token: AtomicU64::new(0),
            holder_len: AtomicUsize::new(0),
            holder: std::array::from_fn(|_| AtomicU8::new(0)),
            count: AtomicUsize::new(0),
            gids: std::array::from_fn(|_| [AtomicU64::new(0), AtomicU64::new(0)]),
            writer: Mutex::new(()),
        }
    }
}

fn gid_words(gid: &Gid) -> [u64; 2] {
    let (a, b) = gid.split_at(8);
    [
        u64::from_le_bytes(a.try_into().expect("8 bytes")),
        u64::from_le_bytes(b.try_into().expect("8 bytes")),
    ]
}

fn words_gid(words: [u64; 2]) -> Gid {
    let mut g = [0u8; GID_LEN];
    g[..8].copy_from_slice(&words[0].to_le_bytes());
    g[8..].copy_from_slice(&words[1].to_le_bytes());
    g
}

/// A name cut to at most `HOLDER_LEN` bytes at a character boundary.
fn clip(name: &str) -> &str {
    if name.len() <= HOLDER_LEN {
        return name;
    }
    let mut end = HOLDER_LEN;
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    &name[..end]
}

/// What a refused request is told (the same words on every path).
pub fn refusal_text(verdict: Verdict, holder: &str, out: &mut String) {
    use std::fmt::Write as _;
    out.clear();
    let _ = match verdict {
        Verdict::Allowed => Ok(()),
        Verdict::NoHolder => write!(
            out,
            "the control lease is required: acquire it with the 'lease' service first"
        ),
        Verdict::HeldByOther => write!(out, "the control lease is held by '{holder}'"),
        Verdict::Lapsed => write!(
            out,
            "the control lease of '{holder}' lapsed: acquire it again with the 'lease' service"
        ),
    };
}

impl std::fmt::Debug for LeaseGate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LeaseGate")
            .field("state", &self.state())
            .finish()
    }
}

impl LeaseGate {
    /// A gate with the lease off (everyone may command) until Python enables it.
    pub fn new() -> LeaseGate {
        LeaseGate::default()
    }

    fn write_with<F: FnOnce(&LeaseGate)>(&self, f: F) {
        let _w = self.writer.lock().unwrap_or_else(|e| e.into_inner());
        self.seq.fetch_add(1, Ordering::AcqRel); // odd: being written
        f(self);
        self.seq.fetch_add(1, Ordering::AcqRel); // even: consistent
    }

    /// Switch the lease on or off (off: every request is allowed).
    pub fn set_enabled(&self, enabled: bool) {
        self.write_with(|g| g.enabled.store(enabled, Ordering::Relaxed));
    }

    /// A new holder (or the same one with other writers): `expires_ns` on CLOCK_MONOTONIC.
    /// GIDs beyond `MAX_WRITERS` are ignored (the caller refuses such a request first).
    pub fn grant(&self, holder: &str, token: u64, gids: &[Gid], expires_ns: i64) {
        let holder = clip(holder).as_bytes();
        self.write_with(|g| {
            for (slot, b) in g.holder.iter().zip(holder) {
                slot.store(*b, Ordering::Relaxed);
            }
            g.holder_len.store(holder.len(), Ordering::Relaxed);
            let n = gids.len().min(MAX_WRITERS);
            for (slot, gid) in g.gids.iter().zip(&gids[..n]) {
                let [a, b] = gid_words(gid);
                slot[0].store(a, Ordering::Relaxed);
                slot[1].store(b, Ordering::Relaxed);
            }
            g.count.store(n, Ordering::Relaxed);
            g.token.store(token, Ordering::Relaxed);
            g.expires_ns.store(expires_ns, Ordering::Relaxed);
        });
    }

    /// Keep the current holder's lease until `expires_ns` (no-op when nobody holds it).
    pub fn renew(&self, expires_ns: i64) {
        self.write_with(|g| {
            if g.expires_ns.load(Ordering::Relaxed) != 0 {
                g.expires_ns.store(expires_ns, Ordering::Relaxed);
            }
        });
    }

    /// Nobody holds the lease from now on. The holder's name is kept, so a refusal can
    /// still say whose lease lapsed.
    pub fn revoke(&self) {
        self.write_with(|g| {
            g.expires_ns.store(0, Ordering::Relaxed);
            g.token.store(0, Ordering::Relaxed);
            g.count.store(0, Ordering::Relaxed);
        });
    }

    /// A consistent copy of the state (for Python and the diagnostics).
    pub fn state(&self) -> LeaseState {
        loop {
            let before = self.seq.load(Ordering::Acquire);
            if before % 2 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let n = self.count.load(Ordering::Relaxed).min(MAX_WRITERS);
            let len = self.holder_len.load(Ordering::Relaxed).min(HOLDER_LEN);
            let bytes: Vec<u8> = self.holder[..len]
                .iter()
                .map(|b| b.load(Ordering::Relaxed))
                .collect();
            let state = LeaseState {
                enabled: self.enabled.load(Ordering::Relaxed),
                expires_ns: self.expires_ns.load(Ordering::Relaxed),
                token: self.token.load(Ordering::Relaxed),
                holder: String::from_utf8_lossy(&bytes).into_owned(),
                gids: self.gids[..n]
                    .iter()
                    .map(|w| {
                        words_gid([w[0].load(Ordering::Relaxed), w[1].load(Ordering::Relaxed)])
                    })
                    .collect(),
            };
            if self.seq.load(Ordering::Acquire) == before {
                return state;
            }
        }
    }

    /// May a message from publisher `gid` command the bus at `now_ns`? On a refusal the
    /// holder's name is copied into `holder` (cleared first; never allocates beyond its
    /// capacity once it has held a name).
    pub fn check_gid(&self, gid: &Gid, now_ns: i64, holder: &mut String) -> Verdict {
        let want = gid_words(gid);
        self.check(now_ns, holder, |g, n| {
            g.gids[..n].iter().any(|w| {
                w[0].load(Ordering::Relaxed) == want[0] && w[1].load(Ordering::Relaxed) == want[1]
            })
        })
    }

    /// May a service request carrying lease `token` command the bus at `now_ns`?
    pub fn check_token(&self, token: u64, now_ns: i64, holder: &mut String) -> Verdict {
        self.check(now_ns, holder, |g, _| {
            token != 0 && g.token.load(Ordering::Relaxed) == token
        })
    }

    fn check<F: Fn(&LeaseGate, usize) -> bool>(
        &self,
        now_ns: i64,
        holder: &mut String,
        is_holder: F,
    ) -> Verdict {
        holder.clear();
        if !self.enabled.load(Ordering::Acquire) {
            return Verdict::Allowed;
        }
        loop {
            holder.clear();
            let before = self.seq.load(Ordering::Acquire);
            if before % 2 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let expires = self.expires_ns.load(Ordering::Relaxed);
            let n = self.count.load(Ordering::Relaxed).min(MAX_WRITERS);
            let mine = expires != 0 && is_holder(self, n);
            let verdict = if !self.enabled.load(Ordering::Relaxed) {
                Verdict::Allowed
            } else if expires != 0 && now_ns < expires {
                if mine {
                    Verdict::Allowed
                } else {
                    Verdict::HeldByOther
                }
            } else if self.holder_len.load(Ordering::Relaxed) > 0 {
                Verdict::Lapsed
            } else {
                Verdict::NoHolder
            };
            if verdict != Verdict::Allowed {
                let len = self.holder_len.load(Ordering::Relaxed).min(HOLDER_LEN);
                let mut bytes = [0u8; HOLDER_LEN];
                for (b, slot) in bytes.iter_mut().zip(&self.holder[..len]) {
                    *b = slot.load(Ordering::Relaxed);
                }
                holder.push_str(&String::from_utf8_lossy(&bytes[..len]));
            }
            if self.seq.load(Ordering::Acquire) == before {
                return verdict;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gid(n: u8) -> Gid {
        let mut g = [0u8; GID_LEN];
        g[0] = n;
        g[15] = n.wrapping_mul(3);
        g
    }

    #[test]
    fn off_allows_everyone() {
        let g = LeaseGate::new();
        let mut h = String::new();
        assert_eq!(g.check_gid(&gid(1), 10, &mut h), Verdict::Allowed);
        assert_eq!(g.check_token(0, 10, &mut h), Verdict::Allowed);
    }

    #[test]
    fn only_the_holder_while_it_lasts() {
        let g = LeaseGate::new();
        g.set_enabled(true);
        let mut h = String::new();
        assert_eq!(g.check_gid(&gid(1), 10, &mut h), Verdict::NoHolder);
        g.grant("/console", 77, &[gid(1), gid(2)], 1_000);
        assert_eq!(g.check_gid(&gid(2), 999, &mut h), Verdict::Allowed);
        assert_eq!(g.check_token(77, 999, &mut h), Verdict::Allowed);
        assert_eq!(g.check_gid(&gid(3), 999, &mut h), Verdict::HeldByOther);
        assert_eq!(h, "/console");
        assert_eq!(g.check_token(78, 999, &mut h), Verdict::HeldByOther);
        assert_eq!(g.check_token(0, 999, &mut h), Verdict::HeldByOther);
        // At the expiry instant it has lapsed, for the holder too.
        assert_eq!(g.check_gid(&gid(1), 1_000, &mut h), Verdict::Lapsed);
        g.renew(5_000);
        assert_eq!(g.check_gid(&gid(1), 1_000, &mut h), Verdict::Allowed);
        g.revoke();
        assert_eq!(g.check_token(77, 1_000, &mut h), Verdict::Lapsed);
        assert_eq!(h, "/console");
        g.renew(9_000); // nobody holds it: stays revoked
        assert_eq!(g.check_gid(&gid(1), 1_000, &mut h), Verdict::Lapsed);
        g.set_enabled(false);
        assert_eq!(g.check_gid(&gid(9), 1_000, &mut h), Verdict::Allowed);
    }

    #[test]
    fn state_is_a_consistent_copy() {
        let g = LeaseGate::new();
        g.set_enabled(true);
        let long = "é".repeat(100);
        g.grant(&long, 5, &[gid(4)], 42);
        let s = g.state();
        assert!(s.enabled);
        assert_eq!((s.token, s.expires_ns, s.gids), (5, 42, vec![gid(4)]));
        assert!(s.holder.len() <= HOLDER_LEN && long.starts_with(&s.holder));
    }

    #[test]
    fn readers_never_see_a_half_written_grant() {
        let g = std::sync::Arc::new(LeaseGate::new());
        g.set_enabled(true);
        let writer = {
            let g = g.clone();
            std::thread::spawn(move || {
                for i in 0..20_000u32 {
                    let n = (i % 2) as u8;
                    g.grant(
                        if n == 0 { "a" } else { "bb" },
                        1 + n as u64,
                        &[gid(n)],
                        i64::MAX,
                    );
                }
            })
        };
        let mut h = String::new();
        for _ in 0..20_000 {
            // Holder "a" always comes with gid(0) and token 1, "bb" with gid(1) and token 2.
            let s = g.state();
            if s.token == 1 {
                assert_eq!((s.holder.as_str(), s.gids[0]), ("a", gid(0)));
            } else if s.token == 2 {
                assert_eq!((s.holder.as_str(), s.gids[0]), ("bb", gid(1)));
            }
            if g.check_gid(&gid(0), 0, &mut h) == Verdict::HeldByOther {
                assert_eq!(h, "bb");
            }
        }
        writer.join().unwrap();
    }

    #[test]
    fn refusals_name_the_holder() {
        let mut t = String::new();
        refusal_text(Verdict::HeldByOther, "/console", &mut t);
        assert_eq!(t, "the control lease is held by '/console'");
        refusal_text(Verdict::Lapsed, "/rig", &mut t);
        assert!(t.starts_with("the control lease of '/rig' lapsed"));
        refusal_text(Verdict::NoHolder, "", &mut t);
        assert!(t.contains("'lease' service"));
    }
}

//! Helpers shared by the tests of the vdbcook crates. Only ever a
//! dev-dependency.

/// The value of `made`, or `None` after a note on stderr when it failed
/// (no GPU adapter, say): a test then skips its checks. Under `CI=true` a
/// failure is a test failure, never a skip.
pub fn or_skip<T, E: std::fmt::Display>(made: Result<T, E>, what: &str) -> Option<T> {
    match made {
        Ok(v) => Some(v),
        Err(e) => {
            assert!(std::env::var("CI").ok().as_deref() != Some("true"), "CI=true and no {what}: {e}");
            eprintln!("note: skipping: no {what}: {e}");
            None
        }
    }
}

/// A small deterministic generator (xorshift64*) for test inputs and
/// corruption corpora: the same seed gives the same stream everywhere.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from `seed` (0, which xorshift cannot leave, is replaced).
    pub fn new(seed: u64) -> Rng {
        Rng(if seed == 0 { 0x9e37_79b9_7f4a_7c15 } else { seed })
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// In `0..n` (`n` > 0; the slight modulo bias does not matter for tests).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n.max(1)
    }

    /// In [0, 1), with 24 random bits.
    pub fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// `n` random bytes.
    pub fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| (self.next_u64() >> 56) as u8).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::Rng;

    #[test]
    fn streams_repeat_and_spread() {
        let (mut a, mut b) = (Rng::new(42), Rng::new(42));
        let xs: Vec<u64> = (0..1000).map(|_| a.next_u64()).collect();
        assert!(xs.iter().all(|&x| x == b.next_u64()));
        let mut r = Rng::new(0);
        let mut hits = [0u32; 10];
        for _ in 0..10_000 {
            hits[r.below(10) as usize] += 1;
            let u = r.unit();
            assert!((0.0..1.0).contains(&u));
        }
        assert!(hits.iter().all(|&h| (900..1100).contains(&h)), "{hits:?}");
        assert_eq!(r.bytes(7).len(), 7);
    }
}

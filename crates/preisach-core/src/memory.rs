//! The memory staircase: the stack of dominant extrema with wiping-out (the paper §2.1,
//! Fig. 3; `docs/method/fast-paths.md`). Generic over the coordinate: integer level indices for the
//! stepwise model, continuous level positions for the interpolated one.
//!
//! Layout: `turns = [m_0, M_1, m_1, M_2, …]` alternates minima (even positions) and
//! maxima (odd positions); `m_0` is the bottom of the range. An odd length means the
//! input is rising from the last minimum, an even length that it is falling from the
//! last maximum. `sums[k]` holds the switched-on mass S_k of the closed pairs up to the
//! minimum at `turns[2k]`, so the output is O(1) and a sample only touches the top.

/// Everett lookup: `E(a, b)` for `a > b` in the memory's coordinate.
pub trait EverettFn<T> {
    fn e(&self, a: T, b: T) -> f64;
}

impl<T, F: Fn(T, T) -> f64> EverettFn<T> for F {
    #[inline(always)]
    fn e(&self, a: T, b: T) -> f64 {
        self(a, b)
    }
}

/// State of a Preisach operator: its dominant extrema and the current input.
#[derive(Debug, Clone, PartialEq)]
pub struct Memory<T> {
    turns: Vec<T>,
    sums: Vec<f64>,
    cur: T,
}

impl<T: Copy + PartialOrd> Memory<T> {
    /// All relays at −1 (negative saturation). `capacity` bounds the depth expected
    /// (n_h + 2 on the level grid), so stepping never allocates.
    pub fn new(bottom: T, capacity: usize) -> Self {
        let mut turns = Vec::with_capacity(capacity.max(2));
        let mut sums = Vec::with_capacity(capacity.max(2) / 2 + 1);
        turns.push(bottom);
        sums.push(0.0);
        Memory { turns, sums, cur: bottom }
    }

    /// Back to negative saturation, keeping the allocation.
    pub fn reset(&mut self) {
        self.turns.truncate(1);
        self.sums.truncate(1);
        self.cur = self.turns[0];
    }

    /// The current (quantized) input.
    #[inline]
    pub fn current(&self) -> T {
        self.cur
    }

    /// Number of stored extrema after the bottom.
    #[inline]
    pub fn depth(&self) -> usize {
        self.turns.len() - 1
    }

    /// `true` while the input is on a rising branch (from the last minimum).
    #[inline]
    pub fn rising(&self) -> bool {
        self.turns.len() % 2 == 1
    }

    /// The dominant extrema after the bottom, then the current input: applying these
    /// values in order to a fresh memory rebuilds this one exactly.
    pub fn snapshot(&self) -> Vec<T> {
        let mut v: Vec<T> = self.turns[1..].to_vec();
        v.push(self.cur);
        v
    }

    /// The stored extrema including the bottom `m_0` (alternating min, max, …).
    pub fn turns(&self) -> &[T] {
        &self.turns
    }

    /// Move the input to `c` (wiping-out included). O(1) amortized, no allocation while
    /// the depth stays within the capacity.
    #[inline]
    pub fn apply<E: EverettFn<T>>(&mut self, c: T, e: &E) {
        let n = self.turns.len();
        if n % 2 == 1 {
            if c >= self.cur {
                self.cur = c;
                self.wipe_rising(c);
            } else {
                self.turns.push(self.cur);
                self.cur = c;
                self.wipe_falling(c);
            }
        } else if c <= self.cur {
            self.cur = c;
            self.wipe_falling(c);
        } else {
            // Falling run ends at `cur`: close the pair (M_K, m_{K-1} .. cur).
            let m_k = self.turns[n - 1];
            let s = self.sums[(n - 2) / 2] + e.e(m_k, self.turns[n - 2]) - e.e(m_k, self.cur);
            self.turns.push(self.cur);
            self.sums.push(s);
            self.cur = c;
            self.wipe_rising(c);
        }
    }

    #[inline]
    fn wipe_rising(&mut self, c: T) {
        // Rising past a stored maximum erases it and the minimum after it.
        let mut n = self.turns.len();
        while n >= 3 && c >= self.turns[n - 2] {
            n -= 2;
            self.sums.pop();
        }
        self.turns.truncate(n);
    }

    #[inline]
    fn wipe_falling(&mut self, c: T) {
        // Falling past a stored minimum erases it and the maximum after it; reaching the
        // bottom returns to negative saturation.
        let mut n = self.turns.len();
        while c <= self.turns[n - 2] {
            if n == 2 {
                n = 1;
                break;
            }
            n -= 2;
            self.sums.pop();
        }
        self.turns.truncate(n);
    }

    /// Switched-on mass S⁺ of the current state.
    #[inline]
    pub fn s_plus<E: EverettFn<T>>(&self, e: &E) -> f64 {
        let n = self.turns.len();
        if n % 2 == 1 {
            self.sums[n / 2] + e.e(self.cur, self.turns[n - 1])
        } else {
            let m = self.turns[n - 1];
            self.sums[(n - 2) / 2] + e.e(m, self.turns[n - 2]) - e.e(m, self.cur)
        }
    }

    /// S⁺ the state would have after moving the input to `c`, without mutating
    /// anything: the wiped extrema are found by binary search (`docs/method/fast-paths.md`, "Closest match
    /// is a search over a monotone function"). O(log depth).
    pub fn peek_s_plus<E: EverettFn<T>>(&self, c: T, e: &E) -> f64 {
        let n = self.turns.len();
        let t = &self.turns;
        if n % 2 == 1 {
            if c >= self.cur {
                self.rising_to(c, n, e)
            } else {
                // Reversal: `cur` becomes a maximum at virtual position n.
                self.falling_to(c, n + 1, self.cur, e)
            }
        } else if c <= self.cur {
            self.falling_to(c, n, t[n - 1], e)
        } else {
            // Reversal: `cur` becomes a minimum at virtual position n.
            let m_k = t[n - 1];
            let s_virtual = self.sums[(n - 2) / 2] + e.e(m_k, t[n - 2]) - e.e(m_k, self.cur);
            let p = self.first_wiped_max(c, n);
            if p < n {
                self.sums[(p - 1) / 2] + e.e(c, t[p - 1])
            } else {
                s_virtual + e.e(c, self.cur)
            }
        }
    }

    /// Smallest odd position p < n with `turns[p] <= c` (maxima decrease with p), or n.
    #[inline]
    fn first_wiped_max(&self, c: T, n: usize) -> usize {
        let k_max = n / 2; // maxima at 1, 3, …, 2·k_max − 1 (those below n)
        let (mut lo, mut hi) = (0usize, k_max);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if self.turns[2 * mid + 1] <= c {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        if lo == k_max {
            n
        } else {
            2 * lo + 1
        }
    }

    /// Rising from the last minimum of `turns[..n]` (n odd) to `c`.
    #[inline]
    fn rising_to<E: EverettFn<T>>(&self, c: T, n: usize, e: &E) -> f64 {
        let p = self.first_wiped_max(c, n);
        let last = if p < n { p - 1 } else { n - 1 };
        self.sums[last / 2] + e.e(c, self.turns[last])
    }

    /// Falling to `c` in a stack of virtual length `n` (even) whose last maximum is
    /// `top` (`turns[n-1]`, or `cur` when n exceeds the stored length).
    #[inline]
    fn falling_to<E: EverettFn<T>>(&self, c: T, n: usize, top: T, e: &E) -> f64 {
        // Minima at even positions 0..n-1 increase; survivors are those < c.
        let k_min = n / 2;
        let (mut lo, mut hi) = (0usize, k_min);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if self.turns[2 * mid] < c {
                lo = mid + 1;
            } else {
                hi = mid;
            }
        }
        if lo == 0 {
            return 0.0; // back at the bottom: every relay off
        }
        let q = 2 * (lo - 1);
        let x = if q + 1 < self.turns.len() { self.turns[q + 1] } else { top };
        self.sums[q / 2] + e.e(x, self.turns[q]) - e.e(x, c)
    }
}

//! The dense NNLS against its oracle: every support enumerated (least squares on it,
//! kept when positive), the best residual taken.

use preisach_core::identify::nnls::nnls;
use proptest::prelude::*;

fn residual(a: &[f64], n: usize, b: &[f64], x: &[f64]) -> f64 {
    b.iter()
        .enumerate()
        .map(|(i, bi)| {
            let r = (0..n).map(|j| a[i * n + j] * x[j]).sum::<f64>() - bi;
            r * r
        })
        .sum::<f64>()
        .sqrt()
}

/// The best residual over all supports whose least-squares solution is non-negative.
fn brute_force(a: &[f64], n: usize, b: &[f64]) -> f64 {
    let m = b.len();
    let mut best = residual(a, n, b, &vec![0.0; n]);
    for mask in 1u32..(1 << n) {
        let s: Vec<usize> = (0..n).filter(|j| mask >> j & 1 == 1).collect();
        let am = nalgebra::DMatrix::<f64>::from_fn(m, s.len(), |i, k| a[i * n + s[k]]);
        let bv = nalgebra::DVector::<f64>::from_column_slice(b);
        let Ok(z) = am.clone().svd(true, true).solve(&bv, 1e-12) else { continue };
        if z.iter().all(|&v| v >= 0.0) {
            let mut x = vec![0.0; n];
            s.iter().zip(z.iter()).for_each(|(&j, &v)| x[j] = v);
            best = best.min(residual(a, n, b, &x));
        }
    }
    best
}

proptest! {
    #[test]
    fn nnls_matches_every_support_enumerated(
        n in 1usize..6, m in 6usize..30, seed in any::<u64>(),
    ) {
        // Random matrix and target from a small LCG (column scales over 6 decades).
        let mut s = seed | 1;
        let mut next = || { s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0 };
        let scales: Vec<f64> = (0..n).map(|_| 10f64.powf(3.0 * next())).collect();
        let a: Vec<f64> = (0..m * n).map(|k| next() * scales[k % n]).collect();
        let b: Vec<f64> = (0..m).map(|_| next()).collect();
        let x = nnls(&a, n, &b).unwrap();
        prop_assert!(x.iter().all(|&v| v >= 0.0));
        let r = residual(&a, n, &b, &x);
        let best = brute_force(&a, n, &b);
        prop_assert!(r <= best * (1.0 + 1e-7) + 1e-12, "nnls {r} vs best support {best}");
    }
}

#[test]
fn nnls_gives_exact_zeros_and_the_exact_solution_when_it_is_positive() {
    // b = A [2, 0, 0.5] exactly: the second column gets an exact zero.
    let a = [1.0, 0.0, 1.0, 0.0, 1.0, 1.0, 1.0, -1.0, 0.0, 2.0, 1.0, 1.0];
    let x = nnls(&a, 3, &[2.5, 0.5, 2.0, 4.5]).unwrap();
    assert!((x[0] - 2.0).abs() < 1e-10 && x[1] == 0.0 && (x[2] - 0.5).abs() < 1e-10, "{x:?}");
}

#[test]
fn nnls_names_bad_input() {
    let e = nnls(&[1.0, 2.0, 3.0], 2, &[1.0, 2.0]).unwrap_err().to_string();
    assert!(e.starts_with("a:"), "{e}");
    let e = nnls(&[1.0, f64::NAN], 1, &[1.0, 2.0]).unwrap_err().to_string();
    assert!(e.contains("a:") && e.contains("NaN"), "{e}");
    let e = nnls(&[1.0, 2.0], 1, &[1.0, f64::INFINITY]).unwrap_err().to_string();
    assert!(e.contains("b:") && e.contains("inf"), "{e}");
}

mod common;

use common::{random_input, random_model, Rng};
use preisach_core::RelayGrid;

#[test]
fn staircase_equals_relay_grid_on_random_inputs_beyond_the_range() {
    let mut rng = Rng::new(1);
    for n_h in [1usize, 2, 3, 7, 20, 45] {
        let model = random_model(&mut rng, n_h);
        let u = random_input(&mut rng, 3000);
        let mut mem = model.memory();
        let mut relays = RelayGrid::new(model.grid().clone());
        let scale = model.everett().total() + model.offset().abs();
        for &x in &u {
            let y = model.step(&mut mem, x);
            relays.apply(x);
            let y_ref = relays.output(model.masses(), model.offset());
            assert!((y - y_ref).abs() <= 1e-12 * scale, "n_h={n_h} u={x}: {y} vs {y_ref}");
        }
    }
}

#[test]
fn staircase_equals_relay_grid_exactly_on_thresholds_and_levels() {
    let mut rng = Rng::new(2);
    let model = random_model(&mut rng, 9);
    let g = model.grid().clone();
    let mut pts: Vec<f64> = g.thresholds().to_vec();
    pts.extend(g.levels());
    let mut u = Vec::new();
    for _ in 0..2000 {
        u.push(pts[(rng.next_u64() % pts.len() as u64) as usize]);
    }
    let mut mem = model.memory();
    let mut relays = RelayGrid::new(g);
    for &x in &u {
        let y = model.step(&mut mem, x);
        relays.apply(x);
        assert!((y - relays.output(model.masses(), model.offset())).abs() < 1e-12 * model.everett().total());
    }
}

#[test]
fn peek_equals_apply_on_a_copy_for_every_level() {
    let mut rng = Rng::new(3);
    let model = random_model(&mut rng, 17);
    let u = random_input(&mut rng, 400);
    let mut mem = model.memory();
    let e = model.e_step();
    for &x in &u {
        model.step(&mut mem, x);
        for k in 0..=17u32 {
            let mut copy = mem.clone();
            copy.apply(k, &e);
            let want = copy.s_plus(&e);
            let got = mem.peek_s_plus(k, &e);
            assert!((want - got).abs() < 1e-12 * model.everett().total(), "level {k}: {got} vs {want}");
        }
    }
}

#[test]
fn interpolated_peek_equals_apply_on_a_copy() {
    let mut rng = Rng::new(4);
    let model = random_model(&mut rng, 11);
    let u = random_input(&mut rng, 300);
    let mut mem = model.interp_memory();
    let e = model.e_interp();
    for &x in &u {
        model.step_interpolated(&mut mem, x);
        for _ in 0..10 {
            let p = rng.range(0.0, 11.0);
            let mut copy = mem.clone();
            copy.apply(p, &e);
            assert!((copy.s_plus(&e) - mem.peek_s_plus(p, &e)).abs() < 1e-12 * model.everett().total());
        }
    }
}

#[test]
fn interpolated_output_equals_stepwise_on_levels() {
    let mut rng = Rng::new(5);
    let model = random_model(&mut rng, 13);
    let levels = model.grid().levels();
    let mut a = model.memory();
    let mut b = model.interp_memory();
    for _ in 0..2000 {
        let x = levels[(rng.next_u64() % levels.len() as u64) as usize];
        let ys = model.step(&mut a, x);
        let yi = model.step_interpolated(&mut b, x);
        assert!((ys - yi).abs() < 1e-12 * model.everett().total());
    }
}

#[test]
fn snapshot_rebuilds_the_memory() {
    let mut rng = Rng::new(6);
    let model = random_model(&mut rng, 25);
    let u = random_input(&mut rng, 500);
    let mut mem = model.memory();
    let mut out = vec![0.0; u.len()];
    model.run(&mut mem, &u, &mut out);
    let snap = model.step_memory_values(&mem);
    let rebuilt = model.step_memory_from(&snap).unwrap();
    assert_eq!(rebuilt, mem);
    let mut im = model.interp_memory();
    for &x in &u {
        model.step_interpolated(&mut im, x);
    }
    let rebuilt = model.interp_memory_from(&model.interp_memory_values(&im)).unwrap();
    assert_eq!(rebuilt.turns().len(), im.turns().len());
}

#[test]
fn stepwise_depth_stays_within_the_preallocated_capacity() {
    let mut rng = Rng::new(7);
    let model = random_model(&mut rng, 30);
    let mut mem = model.memory();
    // Nested oscillation: the deepest staircase the grid allows.
    let n = 30;
    let mut u = Vec::new();
    for k in 0..n / 2 {
        u.push(model.grid().level(n - k));
        u.push(model.grid().level(k + 1));
    }
    for &x in &u {
        model.step(&mut mem, x);
    }
    assert!(mem.depth() <= n + 1);
}

#[test]
fn interpolated_output_is_continuous_at_reversals_inside_diagonal_cells() {
    let mut rng = Rng::new(8);
    let model = random_model(&mut rng, 10);
    let g = model.grid().clone();
    let scale = model.everett().total();
    for _ in 0..200 {
        let mut mem = model.interp_memory();
        let start = rng.range(-1.0, 2.0);
        model.step_interpolated(&mut mem, start);
        let turn = rng.range(-1.0, 2.0);
        let y_turn = model.step_interpolated(&mut mem, turn);
        // Reverse by a hair: the output moves by a hair, however the masses lie.
        let back = if turn > start { turn - 1e-9 * g.delta() } else { turn + 1e-9 * g.delta() };
        let y_back = model.step_interpolated(&mut mem, back);
        assert!((y_back - y_turn).abs() < 1e-6 * scale, "jump {} at {turn}", y_back - y_turn);
    }
}

//! Batch-8 policy forward latency: `Policy::act` against the plain faer path (weights transposed
//! to `[in, out]`, one GEMM per layer), alternating rounds in one process.
use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Instant;
use terl_bench::sac::SacBenchConfig;
use terl_rl::{Policy, Sac};

fn main() {
    let cfg = SacBenchConfig::default().sac_config().unwrap();
    let sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    let rows = 8;
    let mut policy = Policy::new(sac.policy_spec(), rows);
    policy.set_params(&sac.policy_params_f32(), 0).unwrap();
    let net = sac.policy_net();
    let sizes = net.sizes().to_vec();
    let wt: Vec<Vec<f32>> = (0..sizes.len() - 1)
        .map(|l| {
            let (i, o) = (sizes[l], sizes[l + 1]);
            let w = &net.params[net.weight_range(l)];
            let mut t = vec![0.0; i * o];
            for a in 0..o {
                for b in 0..i {
                    t[b * o + a] = w[a * i + b];
                }
            }
            t
        })
        .collect();
    let mut acts: Vec<Vec<f32>> = sizes[1..].iter().map(|&s| vec![0.0; rows * s]).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let obs: Vec<f32> = (0..rows * cfg.obs_dim)
        .map(|_| rng.gen_range(-1.0..1.0))
        .collect();
    let x0: Vec<f32> = (0..rows * sizes[0])
        .map(|_| rng.gen_range(-1.0..1.0))
        .collect();
    let tasks: Vec<usize> = (0..rows).map(|i| i % cfg.num_tasks).collect();
    let mut actions = vec![0.0; rows * cfg.act_dim];
    let mut faer_path = || {
        for l in 0..sizes.len() - 1 {
            let (i, o) = (sizes[l], sizes[l + 1]);
            let (before, rest) = acts.split_at_mut(l);
            let x = if l == 0 { &x0[..] } else { &before[l - 1][..] };
            let y = &mut rest[0];
            matmul(
                MatMut::from_row_major_slice_mut(y, rows, o),
                Accum::Replace,
                MatRef::from_row_major_slice(x, rows, i),
                MatRef::from_row_major_slice(&wt[l], i, o),
                1.0f32,
                Par::Seq,
            );
            let b = &net.params[net.bias_range(l)];
            for r in y.chunks_exact_mut(o) {
                r.iter_mut()
                    .zip(b)
                    .for_each(|(v, &b)| *v = (*v + b).max(0.0));
            }
        }
    };
    let time = |f: &mut dyn FnMut()| {
        for _ in 0..20 {
            f();
        }
        let start = Instant::now();
        let mut n = 0;
        while start.elapsed().as_secs_f64() < 0.2 {
            f();
            n += 1;
        }
        start.elapsed().as_secs_f64() * 1e6 / n as f64
    };
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for _ in 0..15 {
        a.push(time(&mut || faer_path()));
        b.push(time(&mut || {
            policy
                .act(&obs, &tasks, false, &mut rng, &mut actions)
                .unwrap()
        }));
    }
    a.sort_by(|x, y| x.partial_cmp(y).unwrap());
    b.sort_by(|x, y| x.partial_cmp(y).unwrap());
    println!(
        "faer [in,out] GEMMs (forward only): median {:.1} us, min {:.1}",
        a[7], a[0]
    );
    println!(
        "Policy::act (stochastic):           median {:.1} us, min {:.1}",
        b[7], b[0]
    );
}

//! k-NN: CPU brute == CPU grid == Vulkan brute == Vulkan grid == a naive
//! sort of all distances, index for index.

use cvd::exec::CpuBackend;
use cvd::{geom::points, Backend, KnnJob, KnnMethod};
use cvd_tests::{assert_no_validation_errors, reference_knn, vulkan};
use proptest::prelude::*;

#[derive(Clone, Copy, Debug)]
enum Layout {
    Uniform,
    Clustered,
    Duplicates,
    Lattice,
    /// A tight cluster in a crowd, some of its sites repeated: grid cells
    /// of hundreds of sites, searched down their own octree.
    TightInCrowd,
}

fn make_points(layout: Layout, n: usize, seed: u64) -> Vec<[f64; 3]> {
    match layout {
        Layout::Uniform => points::uniform(n, seed),
        Layout::Clustered => points::clustered(n, 4, 0.01, seed),
        Layout::Duplicates => {
            // Every point appears about three times.
            let base = points::uniform(n.div_ceil(3), seed);
            (0..n).map(|i| base[(i * 7919) % base.len()]).collect()
        }
        Layout::Lattice => points::lattice(n, (n as f64).cbrt().ceil() as usize + 1, seed),
        Layout::TightInCrowd => {
            let mut p = points::uniform(n / 3, seed);
            let blob = points::clustered(n - n / 3, 1, 0.002, seed ^ 7);
            p.extend(blob.iter().enumerate().map(|(i, q)| if i % 5 == 4 { blob[i - 1] } else { *q }));
            p
        }
    }
}

fn cpu() -> CpuBackend {
    CpuBackend::new(None).expect("CPU backend")
}

/// Runs both methods on the CPU and on Vulkan (when present) and compares
/// each with the reference, index for index.
fn check_all(job_for: impl Fn(KnnMethod) -> KnnJob) {
    let cpu = cpu();
    let vk = vulkan();
    let mut backends: Vec<&dyn Backend> = vec![&cpu];
    if let Some(v) = vk {
        backends.push(v);
    }
    let reference = reference_knn(&job_for(KnnMethod::Brute));
    for method in [KnnMethod::Brute, KnnMethod::Grid] {
        let job = job_for(method);
        for b in &backends {
            let got = job.run(*b).unwrap_or_else(|e| panic!("{} {method:?}: {e}", b.name()));
            assert_eq!(got.k, job.params.k as usize);
            assert!(got.indices == reference.0, "{} {method:?}: neighbour indices differ from the reference", b.name());
            assert!(got.dist2 == reference.1, "{} {method:?}: distances differ from the reference", b.name());
        }
    }
    if vk.is_some() {
        assert_no_validation_errors();
    }
}

fn layout() -> impl Strategy<Value = Layout> {
    prop_oneof![
        Just(Layout::Uniform),
        Just(Layout::Clustered),
        Just(Layout::Duplicates),
        Just(Layout::Lattice),
        Just(Layout::TightInCrowd)
    ]
}

fn size() -> impl Strategy<Value = usize> {
    prop_oneof![6 => 1usize..=64, 3 => 65usize..=3000, 1 => 3001usize..=20_000]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn site_neighbours_agree(layout in layout(), n in size(), k in 1usize..=128, seed in any::<u64>()) {
        let sites = make_points(layout, n, seed);
        check_all(|m| KnnJob::sites(&sites, k, m).unwrap());
    }

    #[test]
    fn point_queries_agree(layout in layout(), n in size(), nq in 1usize..=500, k in 1usize..=128, seed in any::<u64>()) {
        let sites = make_points(layout, n, seed);
        // Queries spread wider than the sites, so some lie outside the grid.
        let queries: Vec<[f64; 3]> = points::uniform(nq, seed ^ 1).iter().map(|p| p.map(|c| c * 1.4 - 0.2)).collect();
        check_all(|m| KnnJob::points(&sites, &queries, k, m).unwrap());
    }
}

/// Cells of hundreds of sites (a cluster of radius 0.002 among 5 000
/// sites: about 6 000 a cell at the grid's 5 a cell on average), each
/// searched down its octree: the reference's lists, for lists shorter and
/// longer than a leaf, sites and queries inside and beside the cluster.
#[test]
fn dense_cells_give_the_reference_lists() {
    let sites = make_points(Layout::TightInCrowd, 9000, 11);
    let blob = points::clustered(400, 1, 0.003, 12);
    for k in [1, 20, 48, 100] {
        check_all(|m| KnnJob::sites(&sites, k, m).unwrap());
        check_all(|m| KnnJob::points(&sites, &blob, k, m).unwrap());
    }
}

#[test]
fn large_k_returns_every_other_site() {
    let sites = points::uniform(300, 7);
    for k in [256, 299, 300, 1000] {
        check_all(|m| KnnJob::sites(&sites, k, m).unwrap());
        let nn = KnnJob::sites(&sites, k, KnnMethod::Grid).unwrap().run(&cpu()).unwrap();
        assert_eq!(nn.k, k.min(299));
        if k >= 299 {
            let mut first: Vec<u32> = nn.of(0).to_vec();
            first.sort_unstable();
            assert_eq!(first, (1..300).collect::<Vec<u32>>());
        }
    }
}

#[test]
fn tiny_inputs() {
    let one = [[0.5f64, 0.5, 0.5]];
    let nn = KnnJob::sites(&one, 5, KnnMethod::Grid).unwrap().run(&cpu()).unwrap();
    assert_eq!(nn.k, 0);
    assert!(nn.indices.is_empty());
    let two = [[0.0f64, 0.0, 0.0], [1.0, 1.0, 1.0]];
    check_all(|m| KnnJob::sites(&two, 5, m).unwrap());
    check_all(|m| KnnJob::points(&two, &[[0.1, 0.1, 0.1], [5.0, 5.0, 5.0]], 1, m).unwrap());
}

#[test]
fn bad_input_is_rejected_by_name() {
    let nan = [[0.0f64, 0.0, 0.0], [f64::NAN, 0.0, 0.0]];
    let err = KnnJob::sites(&nan, 1, KnnMethod::Grid).unwrap_err().to_string();
    assert!(err.contains("site 1"), "{err}");
    let err = KnnJob::sites(&[[0.0f64; 3]], 0, KnnMethod::Grid).unwrap_err().to_string();
    assert!(err.contains("k must be at least 1"), "{err}");
}

#[test]
fn flat_sites_keep_the_grid_small() {
    // All sites on a plane: the grid must not explode to millions of cells.
    let sites: Vec<[f64; 3]> = points::uniform(5000, 3).iter().map(|p| [p[0], p[1], 0.25]).collect();
    let job = KnnJob::sites(&sites, 10, KnnMethod::Grid).unwrap();
    assert!(job.params.grid.n_cells as usize <= 2 * sites.len() + 64);
    check_all(|m| KnnJob::sites(&sites, 10, m).unwrap());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// A list from candidates (`knn::candidate_query`, a trajectory's
    /// kept lists) is the k-NN list wherever every site nearer than its
    /// last entry is a candidate: given the first `m` of a site's exact
    /// 2k-list, in shuffled order and with farther sites mixed in, its
    /// first `min(k, m)` entries equal the exact list's.
    #[test]
    fn lists_from_candidates_are_the_knn_lists(
        layout in prop_oneof![Just(Layout::Uniform), Just(Layout::Clustered), Just(Layout::Duplicates), Just(Layout::Lattice)],
        n in 20usize..400,
        k in 1usize..24,
        seed in 0u64..1000,
    ) {
        let pts = make_points(layout, n, seed);
        let job = KnnJob::sites(&pts, 2 * k, KnnMethod::Brute).unwrap();
        let (want, _) = reference_knn(&job);
        let kk = job.params.k as usize;
        for q in 0..job.queries.len() {
            let exact = &want[q * kk..(q + 1) * kk];
            let m = (seed as usize + q) % (kk + 1);
            // The first m, reversed, and every third farther site.
            let mut cands: Vec<u32> = exact[..m].iter().rev().copied().collect();
            cands.extend(exact[m..].iter().step_by(3));
            let k = k.min(kk) as u32;
            let (mut nbr, mut d2) = (vec![0u32; k as usize], vec![0u64; k as usize]);
            let at = job.queries[q];
            let found = cvd_kernels::knn::candidate_query(&job.sites, &cands, [at[0], at[1], at[2]], at[3], k, 0, &mut nbr[..], &mut d2[..]);
            prop_assert_eq!(found as usize, cands.len().min(k as usize));
            let sure = m.min(k as usize);
            prop_assert_eq!(&nbr[..sure], &exact[..sure], "query {}", q);
        }
    }
}

//! Fuzz tests of the mesh readers (issue 14 point 6): mutated MSH (4.1 and 2.2), OBJ and
//! STL (ASCII and binary) files never panic, never allocate beyond a bound proportional to
//! their size, and every error names the file (and the line, for a parse error).

include!("../../tests/support/fuzz_common.rs");

use physics_node::mesh::{parse_msh, parse_obj, parse_stl, MeshError};
use proptest::prelude::*;
use std::path::Path;
use std::time::Instant;

const CUBE: [[f64; 3]; 8] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [1.0, 1.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [1.0, 0.0, 1.0],
    [1.0, 1.0, 1.0],
    [0.0, 1.0, 1.0],
];
const TETS: [[usize; 4]; 5] = [
    [1, 2, 4, 5],
    [2, 3, 4, 7],
    [2, 5, 6, 7],
    [4, 5, 7, 8],
    [2, 4, 5, 7],
];
const FACES: [[usize; 3]; 12] = [
    [1, 3, 2],
    [1, 4, 3],
    [5, 6, 7],
    [5, 7, 8],
    [1, 2, 6],
    [1, 6, 5],
    [2, 3, 7],
    [2, 7, 6],
    [3, 4, 8],
    [3, 8, 7],
    [4, 1, 5],
    [4, 5, 8],
];

fn msh41() -> String {
    let n = CUBE.len();
    let mut s = String::from("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n");
    s += &format!("1 {n} 1 {n}\n3 1 0 {n}\n");
    for i in 0..n {
        s += &format!("{}\n", i + 1);
    }
    for p in CUBE {
        s += &format!("{} {} {}\n", p[0], p[1], p[2]);
    }
    s += "$EndNodes\n$Elements\n";
    s += &format!("2 {} 1 {}\n", TETS.len() + 1, TETS.len() + 1);
    s += "2 1 2 1\n1 1 2 3\n";
    s += &format!("3 1 4 {}\n", TETS.len());
    for (i, t) in TETS.iter().enumerate() {
        s += &format!("{} {} {} {} {}\n", i + 2, t[0], t[1], t[2], t[3]);
    }
    s += "$EndElements\n";
    s
}

fn msh22() -> String {
    let mut s = String::from("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n");
    s += &format!("{}\n", CUBE.len());
    for (i, p) in CUBE.iter().enumerate() {
        s += &format!("{} {} {} {}\n", i + 1, p[0], p[1], p[2]);
    }
    s += &format!("$EndNodes\n$Elements\n{}\n", TETS.len());
    for (i, t) in TETS.iter().enumerate() {
        s += &format!("{} 4 2 0 1 {} {} {} {}\n", i + 1, t[0], t[1], t[2], t[3]);
    }
    s += "$EndElements\n";
    s
}

fn obj() -> String {
    let mut s = String::from("# cube\no cube\n");
    for p in CUBE {
        s += &format!("v {} {} {}\n", p[0], p[1], p[2]);
    }
    s += "vn 0 0 1\n";
    for f in FACES {
        s += &format!("f {}//1 {}//1 {}//1\n", f[0], f[1], f[2]);
    }
    s
}

fn stl_ascii() -> String {
    let mut s = String::from("solid cube\n");
    for f in FACES {
        s += "  facet normal 0 0 0\n    outer loop\n";
        for i in f {
            let p = CUBE[i - 1];
            s += &format!("      vertex {} {} {}\n", p[0], p[1], p[2]);
        }
        s += "    endloop\n  endfacet\n";
    }
    s += "endsolid cube\n";
    s
}

fn stl_binary() -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b.extend_from_slice(&(FACES.len() as u32).to_le_bytes());
    for f in FACES {
        b.extend_from_slice(&[0u8; 12]);
        for i in f {
            for c in CUBE[i - 1] {
                b.extend_from_slice(&(c as f32).to_le_bytes());
            }
        }
        b.extend_from_slice(&[0u8; 2]);
    }
    b
}

/// What a reader error must say: the file, and the line when it is a parse error.
fn check_error(e: &MeshError, path: &Path) -> Result<(), TestCaseError> {
    let msg = e.to_string();
    prop_assert!(
        msg.contains(&path.display().to_string()),
        "error does not name the file: {msg}"
    );
    if let MeshError::Parse { line, .. } = e {
        prop_assert!(*line >= 1, "parse error without a line: {msg}");
    }
    Ok(())
}

#[test]
fn mutated_mesh_files_fail_typed_within_bounded_memory() {
    let cases = fuzz_cases(20_000);
    let seeds: Vec<(&str, Vec<u8>)> = vec![
        ("cube41.msh", msh41().into_bytes()),
        ("cube22.msh", msh22().into_bytes()),
        ("cube.obj", obj().into_bytes()),
        ("cube_ascii.stl", stl_ascii().into_bytes()),
        ("cube_binary.stl", stl_binary()),
    ];
    // The seeds themselves are valid.
    parse_msh(&msh41(), Path::new("cube41.msh")).unwrap();
    parse_msh(&msh22(), Path::new("cube22.msh")).unwrap();
    parse_obj(&obj(), Path::new("cube.obj")).unwrap();
    parse_stl(stl_ascii().as_bytes(), Path::new("cube_ascii.stl")).unwrap();
    parse_stl(&stl_binary(), Path::new("cube_binary.stl")).unwrap();

    let started = Instant::now();
    let runs = std::cell::RefCell::new([0u32; 5]);
    let errors = std::cell::RefCell::new([0u32; 5]);
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    });
    let strategy = (0..seeds.len(), proptest::collection::vec(mutation(), 1..6));
    let result = runner.run(&strategy, |(seed, mutations)| {
        let (name, bytes) = &seeds[seed];
        let bytes = mutate(bytes, &mutations);
        let path = Path::new("/fuzz").join(name);
        let (err, peak) = counting::measure(|| {
            if name.ends_with(".msh") {
                let text = String::from_utf8_lossy(&bytes);
                parse_msh(&text, &path).err()
            } else if name.ends_with(".obj") {
                let text = String::from_utf8_lossy(&bytes);
                parse_obj(&text, &path).err()
            } else {
                parse_stl(&bytes, &path).err()
            }
        });
        runs.borrow_mut()[seed] += 1;
        prop_assert!(
            peak <= alloc_limit(bytes.len(), 512),
            "{name}: {peak} bytes allocated for a {}-byte file",
            bytes.len()
        );
        if let Some(e) = err {
            errors.borrow_mut()[seed] += 1;
            check_error(&e, &path)?;
        }
        Ok(())
    });
    let secs = started.elapsed().as_secs_f64();
    let (runs, errors) = (runs.into_inner(), errors.into_inner());
    println!(
        "{{\"fuzz\":\"mesh\",\"cases\":{},\"per_reader\":{{\"msh41\":{},\"msh22\":{},\"obj\":{},\"stl_ascii\":{},\"stl_binary\":{}}},\"errors\":{},\"seconds\":{secs:.2}}}",
        runs.iter().sum::<u32>(),
        runs[0],
        runs[1],
        runs[2],
        runs[3],
        runs[4],
        errors.iter().sum::<u32>()
    );
    result.unwrap();
}

/// Headers that claim huge counts allocate by what the file holds, not by the claim.
#[test]
fn huge_counts_in_headers_do_not_allocate() {
    for (name, text) in [
        (
            "nodes41.msh",
            "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 4000000000 1 4000000000\n3 1 0 4000000000\n1\n",
        ),
        (
            "nodes22.msh",
            "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n9223372036854775807\n1 0 0 0\n",
        ),
        (
            "elements41.msh",
            "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n0 0 0 0\n$EndNodes\n$Elements\n1 99999999999 1 99999999999\n3 1 4 99999999999\n",
        ),
    ] {
        let path = Path::new("/fuzz").join(name);
        let (r, peak) = counting::measure(|| parse_msh(text, &path));
        let e = r.expect_err(name);
        assert!(peak <= alloc_limit(text.len(), 512), "{name}: {peak} bytes");
        assert!(e.to_string().contains(name), "{e}");
    }
    let mut stl = vec![0u8; 84];
    stl[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
    let path = Path::new("/fuzz/huge.stl");
    let (r, peak) = counting::measure(|| parse_stl(&stl, path));
    assert!(r.is_err());
    assert!(
        peak <= alloc_limit(stl.len(), 512),
        "binary STL: {peak} bytes"
    );
}

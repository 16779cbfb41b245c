//! Gmsh MSH 2.2 ASCII writer for tet meshes, and a refined mesh written as a scene names it
//! (`[scene.meniscus] mesh` and `fixed`): the refined truth of the gap diagnosis' self-test
//! and tests build their meshes in code and hand them to a scene through files.

use std::path::{Path, PathBuf};

use super::{refine_once, Midpoints, TetMesh};

/// Writes a tet mesh as Gmsh 2.2 ASCII (scenes read their meshes from files).
pub fn write_msh22(mesh: &TetMesh, path: &Path) -> std::io::Result<()> {
    use std::fmt::Write as _;
    let mut s = String::from("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n");
    let _ = writeln!(s, "{}", mesh.nodes.len());
    for (i, p) in mesh.nodes.iter().enumerate() {
        let _ = writeln!(s, "{} {:.17e} {:.17e} {:.17e}", i + 1, p.x, p.y, p.z);
    }
    let _ = writeln!(s, "$EndNodes\n$Elements\n{}", mesh.tets.len());
    for (i, t) in mesh.tets.iter().enumerate() {
        let _ = writeln!(
            s,
            "{} 4 2 0 1 {} {} {} {}",
            i + 1,
            t[0] + 1,
            t[1] + 1,
            t[2] + 1,
            t[3] + 1
        );
    }
    s += "$EndElements\n";
    std::fs::write(path, s)
}

/// A refined mesh and the files a scene names it by.
#[derive(Debug, Clone)]
pub struct RefinedFiles {
    pub mesh: TetMesh,
    /// Its held nodes.
    pub fixed: Vec<usize>,
    /// The Gmsh 2.2 file (`[scene.meniscus] mesh`).
    pub msh: PathBuf,
    /// The held-node list (`[scene.meniscus] fixed`).
    pub fixed_list: PathBuf,
}

/// A scene's mesh refined once ([`refine_once`], its boundary midpoints as `midpoints` says)
/// and written into `dir` as Gmsh 2.2 with its fixed-node list, so a scene can name it.
pub fn write_refined_once(
    mesh: &TetMesh,
    fixed: &[usize],
    midpoints: Midpoints,
    dir: &Path,
) -> std::io::Result<RefinedFiles> {
    let (fine, fine_fixed) = refine_once(mesh, fixed, midpoints);
    std::fs::create_dir_all(dir)?;
    let msh = dir.join("refined_once.msh");
    write_msh22(&fine, &msh)?;
    let list = dir.join("refined_once_fixed.txt");
    let held: Vec<String> = fine_fixed.iter().map(|i| i.to_string()).collect();
    std::fs::write(&list, held.join(" "))?;
    Ok(RefinedFiles {
        mesh: fine,
        fixed: fine_fixed,
        msh,
        fixed_list: list,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::boxes::box_mesh;
    use crate::mesh::read_msh;

    #[test]
    fn a_written_mesh_reads_back_the_same() {
        let dir = std::env::temp_dir().join(format!("msh_write_{}", std::process::id()));
        let mesh = box_mesh(0.02, 0.01, 0.005, 3, 2, 1);
        let held: Vec<usize> = (0..12).collect(); // the bottom layer (4 × 3 nodes)
        let files = write_refined_once(&mesh, &held, Midpoints::Flat, &dir).unwrap();
        let read = read_msh(&files.msh).unwrap();
        let fixed = crate::mesh::read_fixed_nodes(&files.fixed_list, files.mesh.nodes.len());
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(
            read.mesh, files.mesh,
            "17 significant digits round-trip exactly"
        );
        let fixed = fixed.unwrap();
        assert_eq!(fixed, refine_once(&mesh, &held, Midpoints::Flat).1);
        assert_eq!(fixed, files.fixed);
        assert!(!fixed.is_empty());
    }
}

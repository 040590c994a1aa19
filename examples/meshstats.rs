use radiosity::mesh::{Mesh, MeshSettings};
fn main() {
    let name = std::env::args().nth(1).unwrap_or("cornell".into());
    let scene = radiosity::scene::open(&name).unwrap();
    let mesh = Mesh::build(&scene, &MeshSettings::default());
    for (i, p) in mesh.polygons.iter().enumerate() {
        let sp = &scene.polygons[i];
        println!(
            "{:20} n {:?} c {:?} patches {:?} elements/patch {:?}",
            scene.nodes[p.node],
            sp.normal,
            sp.centre(),
            p.patch_grid,
            p.element_grid
        );
    }
    println!(
        "total patches {} elements {}",
        mesh.patches.len(),
        mesh.elements.len()
    );
}

# Mesh, refinement and texture (src/evdense/mesh/, refine/, texture/): the fused cloud of a dense workspace
# results/{dataset}/mvs/{source}/ -> mesh.ply (poisson | visibility) -> refined.ply -> textured/.
# The workspace folder (sparse/, images/) is not a declared output of run_mvs; fused.ply stands
# for it, and the scripts read the cameras and images next to it.

# Wildcard constraints are per rule: {method} means something else in other rules.


def mesh_dir(dataset, source, method=None):
    """results/{dataset}/mesh/{source}/{method} (method defaults to config mesh.method)."""
    return LAYOUT.mesh_dir(dataset, source, method or config["mesh"]["method"])


def mesh_sections(*names):
    """The sections of config `mesh` a rule reads: its params, so that changing another section
    (say `mesh.texture`) does not rerun this rule."""
    return {k: config["mesh"][k] for k in names}


def mesh_product_names():
    """Names of the mesh products handed to the evaluation, in the order of mesh_products()."""
    return ["mesh", "refined", "textured"]


def mesh_products(dataset, source):
    """The mesh products of a source with the configured method: raw mesh, refined, textured OBJ."""
    return list(LAYOUT.mesh_products(dataset, source, config["mesh"]["method"]))


rule mesh_surface:
    input:
        cloud="results/{dataset}/mvs/{source}/fused.ply",
    output:
        mesh="results/{dataset}/mesh/{source}/{method}/mesh.ply",
    log:
        "results/{dataset}/logs/mesh_surface/{source}_{method}.log",
    benchmark:
        "results/{dataset}/benchmarks/mesh_surface/{source}_{method}.tsv"
    wildcard_constraints:
        source=r"[^/]+",
        method="poisson|visibility",
    threads: 1
    params:
        conf=lambda w: mesh_sections("poisson", "visibility", "cleanup"),
    script:
        "../scripts/mesh_surface.py"


rule refine_mesh:
    input:
        mesh="results/{dataset}/mesh/{source}/{method}/mesh.ply",
        cloud="results/{dataset}/mvs/{source}/fused.ply",
    output:
        mesh="results/{dataset}/mesh/{source}/{method}/refined.ply",
        stats="results/{dataset}/mesh/{source}/{method}/refined.json",
    log:
        "results/{dataset}/logs/refine_mesh/{source}_{method}.log",
    benchmark:
        "results/{dataset}/benchmarks/refine_mesh/{source}_{method}.tsv"
    wildcard_constraints:
        source=r"[^/]+",
        method="poisson|visibility",
    threads: 1
    params:
        conf=lambda w: config["mesh"]["refine"],
    script:
        "../scripts/refine_mesh.py"


rule texture_mesh:
    input:
        mesh="results/{dataset}/mesh/{source}/{method}/refined.ply",
        cloud="results/{dataset}/mvs/{source}/fused.ply",
    output:
        obj="results/{dataset}/mesh/{source}/{method}/textured/mesh.obj",
        mtl="results/{dataset}/mesh/{source}/{method}/textured/mesh.mtl",
        texture="results/{dataset}/mesh/{source}/{method}/textured/mesh_texture.png",
        colored="results/{dataset}/mesh/{source}/{method}/textured/mesh_colored.ply",
        glb="results/{dataset}/mesh/{source}/{method}/textured/mesh.glb",
        stats="results/{dataset}/mesh/{source}/{method}/textured/texture.json",
    log:
        "results/{dataset}/logs/texture_mesh/{source}_{method}.log",
    benchmark:
        "results/{dataset}/benchmarks/texture_mesh/{source}_{method}.tsv"
    wildcard_constraints:
        source=r"[^/]+",
        method="poisson|visibility",
    threads: 1
    params:
        conf=lambda w: config["mesh"]["texture"],
    script:
        "../scripts/texture_mesh.py"

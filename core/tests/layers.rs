//! The core's dependency direction, checked on its sources: a module imports only from the
//! layers below its own, and nothing the renderer runs on reads a scene description.
//!
//! Layers, bottom up (ARCHITECTURE.md states the same):
//! 0. `sampling`, `texture`, `settings`, `alloc`, `cpu`
//! 1. `geometry`
//! 2. `accel`, `camera`, `film`, `material`, `medium`
//! 3. `light`
//! 4. the scene at render time: `scene` (mod.rs), `scene/aggregate`, `scene/shading`,
//!    `scene/job`
//! 5. `integrator`
//!
//! The front ends (`scene/desc`, `scene/json`, `scene/gltf`, `scene/image`, `scene/files`)
//! and the builder
//! (`scene/build`) produce the runtime from files; they may use any layer but the integrators,
//! and no layer may use them. Test modules (after `#[cfg(test)]`) are not checked: tests may
//! describe scenes.

use std::path::{Path, PathBuf};

/// The layer of a source file (path relative to `src/`), or `None` for a front end.
fn layer_of_file(rel: &str) -> Option<u32> {
    let first = rel.split('/').next().unwrap().trim_end_matches(".rs");
    Some(match first {
        "sampling" | "texture" | "settings" | "alloc" | "cpu" => 0,
        "geometry" => 1,
        "accel" | "camera" | "film" | "material" | "medium" => 2,
        "light" => 3,
        "scene" => match rel {
            "scene/mod.rs" | "scene/aggregate.rs" | "scene/shading.rs" | "scene/job.rs" => 4,
            _ => return None,
        },
        "integrator" => 5,
        "lib" => 6,
        other => panic!("src/{rel}: module '{other}' has no layer: add it to this test"),
    })
}

/// What `crate::<path>` names: a layer, or `None` for a front end.
fn layer_of_path(path: &str) -> Option<u32> {
    let mut parts = path.split("::");
    let top = parts.next().unwrap();
    match top {
        "scene" => match parts.next() {
            Some("desc" | "json" | "gltf" | "image" | "build" | "files") => None,
            _ => Some(4),
        },
        // Items re-exported at the crate root.
        "Scene" | "RenderJob" | "SceneError" => Some(4),
        "load_scene" | "load_scene_with" => None,
        "render" | "render_tile" | "RenderProgress" => Some(5),
        "Film" | "TileAccum" => Some(2),
        "IntegratorKind" | "RenderSettings" | "RenderOverrides" | "SettingsError" | "Tile" => {
            Some(0)
        }
        "RENDER_VERSION" => Some(0),
        _ => layer_of_file(top),
    }
}

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            sources(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The `crate::` paths a file's code (not its comments, not its tests) refers to, with the
/// front-end modules it reaches through `super::`.
fn references(text: &str, rel: &str) -> Vec<String> {
    let code = text.split("#[cfg(test)]").next().unwrap();
    let mut out = Vec::new();
    for line in code.lines() {
        let line = line.trim_start();
        if line.starts_with("//") {
            continue;
        }
        let mut rest = line;
        while let Some(i) = rest.find("crate::") {
            rest = &rest[i + "crate::".len()..];
            if let Some(group) = rest.strip_prefix('{') {
                // `use crate::{A, b::C};`
                let end = group.find('}').unwrap_or(group.len());
                out.extend(group[..end].split(',').map(|s| s.trim().to_string()));
            } else {
                let end = rest
                    .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                    .unwrap_or(rest.len());
                out.push(rest[..end].trim_end_matches(':').to_string());
            }
        }
        // Inside `scene/`, front ends are reached as `super::desc` etc.
        if rel.starts_with("scene/") {
            for m in ["desc", "json", "gltf", "image", "build", "files"] {
                if line.contains(&format!("super::{m}")) {
                    out.push(format!("scene::{m}"));
                }
            }
        }
    }
    out.retain(|s| !s.is_empty());
    out
}

/// Whether `f` is a test module in a file of its own: `tests.rs` that its folder's `mod.rs`
/// declares as `#[cfg(test)] mod tests;` (tests, like `#[cfg(test)]` modules, are not checked).
fn is_test_module_file(f: &Path) -> bool {
    f.file_name().is_some_and(|n| n == "tests.rs")
        && std::fs::read_to_string(f.with_file_name("mod.rs"))
            .is_ok_and(|m| m.contains("#[cfg(test)]\nmod tests;"))
}

#[test]
fn no_module_imports_from_a_layer_above_it_or_from_a_front_end() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let mut wrong = Vec::new();
    for f in &files {
        let rel = f
            .strip_prefix(&src)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        let layer = layer_of_file(&rel);
        if is_test_module_file(f) {
            continue;
        }
        let text = std::fs::read_to_string(f).unwrap();
        for path in references(&text, &rel) {
            let target = layer_of_path(&path);
            let same_module =
                path.split("::").next() == rel.split('/').next().map(|s| s.trim_end_matches(".rs"));
            let ok = match (layer, target) {
                // A front end may use any layer but the integrators, and the other front ends.
                (None, Some(t)) => t < 5,
                (None, None) => true,
                // No layer uses a front end.
                (Some(_), None) => false,
                (Some(l), Some(t)) => t < l || (t == l && same_module),
            };
            if !ok {
                wrong.push(format!("src/{rel}: crate::{path}"));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports against the layering (see this test's header):\n{}",
        wrong.join("\n")
    );
    assert!(files.len() > 40, "found only {} sources", files.len());
}

#[test]
fn the_checker_sees_imports() {
    let refs = references(
        "use crate::scene::desc::Projection;\nuse crate::{RenderJob, geometry::Ray};\n// crate::light\nlet x = super::desc::X;\n#[cfg(test)]\nuse crate::integrator;",
        "scene/job.rs",
    );
    assert_eq!(
        refs,
        [
            "scene::desc::Projection",
            "RenderJob",
            "geometry::Ray",
            "scene::desc"
        ]
    );
    assert_eq!(layer_of_path("scene::desc::Projection"), None);
    assert_eq!(layer_of_path("light::Light"), Some(3));
}

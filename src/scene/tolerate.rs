//! What real files carry that the renderer can safely do without: required
//! extensions that change nothing diffuse, and textures whose only sources
//! are image formats offered by extensions (DDS, KTX2, WebP...). The glTF
//! crate refuses both; this pass rewrites the JSON so it does not, and says
//! what it ignored (one warning each). Any other required extension is
//! still an error.

use serde_json::Value;

/// Required extensions that change only specular or other non-diffuse
/// response (or only offer other image formats): warned about and ignored.
pub const IGNORABLE: [&str; 13] = [
    "AMD_split_roughnessMetallic",
    "KHR_materials_specular",
    "KHR_materials_ior",
    "KHR_materials_clearcoat",
    "KHR_materials_sheen",
    "KHR_materials_iridescence",
    "KHR_materials_anisotropy",
    "KHR_materials_pbrSpecularGlossiness",
    "KHR_materials_variants",
    "KHR_texture_basisu",
    "MSFT_texture_dds",
    "EXT_texture_webp",
    "EXT_texture_avif",
];

/// Extensions that offer a texture's image in another format.
const IMAGE_FORMATS: [&str; 4] = [
    "MSFT_texture_dds",
    "KHR_texture_basisu",
    "EXT_texture_webp",
    "EXT_texture_avif",
];

/// The glTF JSON of `bytes` (a .gltf text or a GLB) made acceptable to the
/// glTF crate where that loses nothing diffuse: `Some(new bytes)` when it
/// changed something (with a warning per change in `warnings`), `None` when
/// nothing needed changing or the file is not JSON we can read (the parser
/// proper then says why).
pub fn tolerate(bytes: &[u8], warnings: &mut Vec<String>) -> Option<Vec<u8>> {
    let glb = if bytes.starts_with(b"glTF") {
        Some(gltf::Glb::from_slice(bytes).ok()?)
    } else {
        None
    };
    let json: &[u8] = glb.as_ref().map_or(bytes, |g| &g.json);
    let mut doc: Value = serde_json::from_slice(json).ok()?;
    let mut changed = drop_ignorable_required(&mut doc, warnings);
    changed |= give_textures_sources(&mut doc, warnings);
    if !changed {
        return None;
    }
    let text = serde_json::to_vec(&doc).ok()?;
    match glb {
        None => Some(text),
        Some(g) => {
            let mut json = text;
            // GLB chunks are 4-byte aligned, padded with spaces.
            while json.len() % 4 != 0 {
                json.push(b' ');
            }
            let out = gltf::Glb {
                header: g.header,
                json: json.into(),
                bin: g.bin,
            };
            let mut buf = Vec::new();
            out.to_writer(&mut buf).ok()?;
            Some(buf)
        }
    }
}

/// Removes the [`IGNORABLE`] names from `extensionsRequired`.
fn drop_ignorable_required(doc: &mut Value, warnings: &mut Vec<String>) -> bool {
    let Some(required) = doc
        .get_mut("extensionsRequired")
        .and_then(Value::as_array_mut)
    else {
        return false;
    };
    let before = required.len();
    required.retain(|e| {
        let name = e.as_str().unwrap_or("");
        let ignore = IGNORABLE.contains(&name);
        if ignore {
            warnings.push(format!(
                "required extension {name} changes nothing the diffuse solution uses: ignored"
            ));
        }
        !ignore
    });
    required.len() != before
}

/// Gives each texture without a `source` the image an image-format
/// extension offers for it (the renderer decodes only PNG and JPEG; a
/// texture it cannot decode falls back to its material's factor).
fn give_textures_sources(doc: &mut Value, warnings: &mut Vec<String>) -> bool {
    let Some(textures) = doc.get_mut("textures").and_then(Value::as_array_mut) else {
        return false;
    };
    let mut fixed = Vec::new();
    for (i, t) in textures.iter_mut().enumerate() {
        if t.get("source").is_some() {
            continue;
        }
        let offered = IMAGE_FORMATS.iter().find_map(|ext| {
            t.pointer(&format!("/extensions/{ext}/source"))
                .and_then(Value::as_u64)
                .map(|s| (*ext, s))
        });
        if let Some((ext, source)) = offered {
            t["source"] = Value::from(source);
            fixed.push(format!("{i} ({ext})"));
        }
    }
    if fixed.is_empty() {
        return false;
    }
    warnings.push(format!(
        "textures {} have only images in formats an extension offers: ignored (their materials' factors stand in)",
        fixed.join(", ")
    ));
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ignorable_extensions_and_dds_only_textures_are_tolerated_with_warnings() {
        let doc = serde_json::json!({
            "asset": {"version": "2.0"},
            "extensionsUsed": ["AMD_split_roughnessMetallic", "MSFT_texture_dds", "EXT_unknown"],
            "extensionsRequired": ["AMD_split_roughnessMetallic", "EXT_unknown"],
            "images": [{"uri": "a.dds"}],
            "textures": [{"extensions": {"MSFT_texture_dds": {"source": 0}}}],
        });
        let mut warnings = Vec::new();
        let out = tolerate(&serde_json::to_vec(&doc).unwrap(), &mut warnings).expect("changed");
        let out: Value = serde_json::from_slice(&out).unwrap();
        assert_eq!(
            out["extensionsRequired"],
            serde_json::json!(["EXT_unknown"])
        );
        assert_eq!(out["textures"][0]["source"], 0);
        assert_eq!(warnings.len(), 2, "{warnings:?}");
        assert!(warnings[0].contains("AMD_split_roughnessMetallic"));
    }

    #[test]
    fn a_file_that_needs_nothing_is_left_alone() {
        let doc = serde_json::json!({"asset": {"version": "2.0"}});
        let mut warnings = Vec::new();
        assert!(tolerate(&serde_json::to_vec(&doc).unwrap(), &mut warnings).is_none());
        assert!(warnings.is_empty());
    }
}

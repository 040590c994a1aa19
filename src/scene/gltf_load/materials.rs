//! Materials as the loader reads them: the specification's ranges, the
//! diffuse reflectance (base colour times one less metallic, reflectance 1
//! clamped), emission, and base-colour textures decoded once.

use super::*;

pub(super) struct Material {
    pub(super) reflectance: [f32; 3],
    pub(super) emission: [f32; 3],
    pub(super) double_sided: bool,
    /// The base-colour texture, if it loaded.
    pub(super) texture: Option<MaterialTexture>,
    /// The emissive texture, if it loaded (its factor: emissiveFactor
    /// times the emissive strength).
    pub(super) emissive: Option<MaterialTexture>,
    /// `alphaMode: MASK`: where the base colour's alpha cuts it out.
    pub(super) mask: Option<crate::scene::mask::Mask>,
}

/// A material's base-colour texture as its primitives map it.
pub(super) struct MaterialTexture {
    pub(super) texture: Arc<TextureRef>,
    /// The TEXCOORD set.
    pub(super) set: u32,
    /// `KHR_texture_transform` as a 2 x 3 affine matrix (rows).
    pub(super) transform: [[f32; 3]; 2],
    /// What the texels are multiplied by: baseColorFactor times
    /// (1 - metallic), unclamped, or emissiveFactor times the strength.
    pub(super) factor: [f32; 3],
}

/// `KHR_texture_transform`'s offset, rotation and scale as the 2 x 3
/// matrix T(offset) R(rotation) S(scale) the extension defines.
fn transform_matrix(offset: [f32; 2], rotation: f32, scale: [f32; 2]) -> [[f32; 3]; 2] {
    let (s, c) = rotation.sin_cos();
    [
        [c * scale[0], s * scale[1], offset[0]],
        [-s * scale[0], c * scale[1], offset[1]],
    ]
}

/// The glTF specification's ranges for a material's factors: base colour,
/// emission and metallic in [0, 1], the emissive strength finite and >= 0.
/// A reflectance above 1 would create energy (a room 7x too bright), so it
/// is an error, not a clamp.
fn check_ranges(
    what: &str,
    base: [f32; 3],
    e: [f32; 3],
    metallic: f32,
    strength: f32,
) -> Result<(), String> {
    let unit = |x: f32| x.is_finite() && (0.0..=1.0).contains(&x);
    if !base.iter().all(|&x| unit(x)) {
        return Err(format!(
            "{what}: baseColorFactor {base:?} is outside [0, 1] (the reflectance must not exceed 1)"
        ));
    }
    if !e.iter().all(|&x| unit(x)) {
        return Err(format!(
            "{what}: emissiveFactor {e:?} is outside [0, 1] (scale it with KHR_materials_emissive_strength)"
        ));
    }
    if !unit(metallic) {
        return Err(format!(
            "{what}: metallicFactor {metallic} is outside [0, 1]"
        ));
    }
    if !(strength.is_finite() && strength >= 0.0) {
        return Err(format!(
            "{what}: KHR_materials_emissive_strength {strength} must be finite and >= 0"
        ));
    }
    Ok(())
}

/// The material `m`'s `alphaMode: MASK` (its cutoff, glTF's default 0.5,
/// and `factor`, the baseColorFactor's alpha); `BLEND` is opaque, said in
/// `warnings`.
fn alpha_mode(
    m: &gltf::Material,
    what: &str,
    factor: f32,
    warnings: &mut Vec<String>,
) -> Option<crate::scene::mask::Mask> {
    if m.alpha_mode() == gltf::material::AlphaMode::Blend {
        warnings.push(format!(
            "{what}: alphaMode BLEND is not see-through here: its surfaces are treated as opaque"
        ));
    }
    (m.alpha_mode() == gltf::material::AlphaMode::Mask).then(|| crate::scene::mask::Mask {
        cutoff: m.alpha_cutoff().unwrap_or(0.5),
        factor,
    })
}

impl Loader<'_> {
    /// The primitive's material, checked against the glTF specification's
    /// ranges: baseColorFactor and emissiveFactor in [0, 1], the emissive
    /// strength finite and >= 0. A reflectance above 1 would create energy
    /// (a room 7x too bright), so it is an error, not a clamp.
    pub(super) fn material(
        &mut self,
        prim: &gltf::Primitive,
        node: &str,
        clamped: &mut Vec<String>,
    ) -> Result<Material, SceneError> {
        let m = prim.material();
        let what = m.name().map_or_else(
            || "the default material".to_string(),
            |n| format!("material '{n}'"),
        );
        let bad = |message: String| SceneError::BadMaterial {
            path: self.path.clone(),
            node: node.to_string(),
            message,
        };
        let pbr = m.pbr_metallic_roughness();
        let base = pbr.base_color_factor();
        let metallic = pbr.metallic_factor();
        let strength = m.emissive_strength().unwrap_or(1.0);
        let e = m.emissive_factor();
        check_ranges(&what, [base[0], base[1], base[2]], e, metallic, strength).map_err(bad)?;
        let mask = alpha_mode(&m, &what, base[3], clamped);
        if metallic >= 1.0 && base[..3].iter().any(|&x| x > 0.0) {
            // glTF's default when a material gives no metallicFactor.
            clamped.push(format!(
                "{what}: metallicFactor 1 (fully metal): no diffuse reflectance, so it absorbs all light here"
            ));
        }
        let factor = [0, 1, 2].map(|c| base[c] * (1.0 - metallic));
        let texture = pbr
            .base_color_texture()
            .and_then(|info| self.material_texture(&info, &what, factor, "base colour"));
        let (emission, emissive) = self.emission(&m, &what, e.map(|x| x * strength));
        if let Some(t) = &texture {
            // The texture's mean stands for the polygon; its elements get
            // their own (see `super::texture`).
            let mean = t.texture.texture.mean();
            let reflectance = [0, 1, 2]
                .map(|c| (factor[c] * mean[c]).min(crate::scene::texture::MAX_REFLECTANCE));
            return Ok(Material {
                reflectance,
                emission,
                double_sided: m.double_sided(),
                texture,
                emissive,
                mask,
            });
        }
        // glTF's implicit reflectance of 1 (no factor, no texture) is
        // rarely meant and never converges in a closed room: 0.95 instead,
        // said once per material. A factor the file writes is the author's,
        // 1 included. A metal's diffuse part is (1 - metallic) of its base
        // colour (glTF's BRDF); what it reflects specularly is not modelled.
        let written = m
            .index()
            .is_some_and(|i| self.explicit_base.get(i) == Some(&true));
        let implicit = |x: f32| !written && x >= 1.0;
        let reflectance = [base[0], base[1], base[2]]
            .map(|x| if implicit(x) { CLAMPED } else { x } * (1.0 - metallic));
        if base[..3].iter().any(|&x| implicit(x)) {
            clamped.push(format!(
                "{what}: no baseColorFactor, so glTF's default reflectance of 1, which never converges in a closed scene: clamped to {CLAMPED}"
            ));
        }
        Ok(Material {
            reflectance,
            emission,
            double_sided: m.double_sided(),
            texture: None,
            emissive,
            mask,
        })
    }

    /// The material `m`'s emission (`factor` the emissive factor times the
    /// strength) and its emissive texture. glTF: emission = emissiveFactor
    /// x emissiveTexture; a texture under a black factor emits nothing and
    /// is not read. The emission is the texture's mean times the factor:
    /// what stands in where a polygon lacks coordinates.
    fn emission(
        &mut self,
        m: &gltf::Material,
        what: &str,
        factor: [f32; 3],
    ) -> ([f32; 3], Option<MaterialTexture>) {
        let emissive = m
            .emissive_texture()
            .filter(|_| factor.iter().any(|&x| x > 0.0))
            .and_then(|info| self.material_texture(&info, what, factor, "emissive"));
        let emission = emissive.as_ref().map_or(factor, |t| {
            let mean = t.texture.texture.mean();
            [0, 1, 2].map(|c| factor[c] * mean[c])
        });
        (emission, emissive)
    }

    /// A material's `kind` texture (base colour or emissive) as its
    /// polygons map it: the image (`None` when it cannot be had), its
    /// coordinate set and transform.
    pub(super) fn material_texture(
        &mut self,
        info: &gltf::texture::Info,
        what: &str,
        factor: [f32; 3],
        kind: &str,
    ) -> Option<MaterialTexture> {
        let texture = self.texture(&info.texture(), what, kind)?;
        let (mut set, mut transform) =
            (info.tex_coord(), transform_matrix([0.0; 2], 0.0, [1.0; 2]));
        if let Some(t) = info.texture_transform() {
            transform = transform_matrix(t.offset(), t.rotation(), t.scale());
            set = t.tex_coord().unwrap_or(set);
        }
        Some(MaterialTexture {
            texture,
            set,
            transform,
            factor,
        })
    }

    /// The texture `texture` (sRGB, as glTF's base colour and emissive
    /// textures are), decoded once (PNG or JPEG, from a file beside the
    /// scene, a data URI or a buffer view); `None`, with a warning naming
    /// the image and its `kind`, when it cannot be had (the material's
    /// factor then stands in).
    pub(super) fn texture(
        &mut self,
        texture: &gltf::Texture,
        material: &str,
        kind: &str,
    ) -> Option<Arc<TextureRef>> {
        let index = texture.index();
        if let Some(t) = self.textures.get(&index) {
            return t.clone();
        }
        let image = texture.source();
        let label = match image.source() {
            gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => uri.to_string(),
            _ => image
                .name()
                .map_or_else(|| format!("images[{}]", image.index()), str::to_string),
        };
        let decoded = self.image_bytes(&image).and_then(|bytes| {
            let mime = match image::guess_format(&bytes) {
                Ok(image::ImageFormat::Jpeg) => "image/jpeg",
                _ => "image/png",
            };
            image::load_from_memory(&bytes)
                .map(|i| (i.to_rgba8(), (bytes, mime.to_string())))
                .map_err(|e| e.to_string())
        });
        let sampler = texture.sampler();
        let wrap = [
            Wrap::from_gltf(sampler.wrap_s()),
            Wrap::from_gltf(sampler.wrap_t()),
        ];
        let out = match decoded {
            Ok((img, encoded)) => {
                let (w, h) = (img.width() as usize, img.height() as usize);
                let texels: Vec<[u8; 4]> = img.pixels().map(|p| p.0).collect();
                Some(Arc::new(TextureRef {
                    index,
                    texture: Texture::from_srgb8(&label, w, h, &texels, wrap),
                    encoded,
                }))
            }
            Err(why) => {
                self.scene.warnings.push(format!(
                    "{material}: {kind} texture '{label}' cannot be used ({why}): its factor stands in"
                ));
                None
            }
        };
        self.textures.insert(index, out.clone());
        out
    }

    /// The encoded bytes of `image`.
    pub(super) fn image_bytes(&self, image: &gltf::Image) -> Result<Vec<u8>, String> {
        match image.source() {
            gltf::image::Source::View { view, .. } => {
                let buffer = self
                    .buffers
                    .get(view.buffer().index())
                    .ok_or("its buffer is missing")?;
                buffer
                    .0
                    .get(view.offset()..view.offset() + view.length())
                    .map(<[u8]>::to_vec)
                    .ok_or_else(|| "its buffer view runs past its buffer".to_string())
            }
            gltf::image::Source::Uri { uri, .. } => {
                if let Some(rest) = uri.strip_prefix("data:") {
                    let (_, data) = rest
                        .split_once(";base64,")
                        .ok_or("a data URI that is not base64")?;
                    use base64::Engine;
                    return base64::engine::general_purpose::STANDARD
                        .decode(data)
                        .map_err(|e| e.to_string());
                }
                let base = self.base.as_deref().ok_or("no folder to find it in")?;
                std::fs::read(base.join(percent_decode(uri))).map_err(|e| e.to_string())
            }
        }
    }
}

impl MaterialTexture {
    pub(super) fn apply(&self, uv: [f32; 2]) -> Vec2 {
        let m = &self.transform;
        Vec2::new(
            m[0][0] * uv[0] + m[0][1] * uv[1] + m[0][2],
            m[1][0] * uv[0] + m[1][1] * uv[1] + m[1][2],
        )
    }
}

/// Per material of the glTF (or GLB) `bytes`, whether it writes
/// `pbrMetallicRoughness.baseColorFactor` (the parsed document cannot
/// tell: it gives glTF's default, 1, either way). Empty where the JSON
/// does not parse (the full parse says why).
pub(super) fn explicit_base_colours(bytes: &[u8]) -> Vec<bool> {
    let Some(json) = super::json_chunk(bytes) else {
        return Vec::new();
    };
    let Ok(root) = serde_json::from_slice::<serde_json::Value>(&json) else {
        return Vec::new();
    };
    root["materials"]
        .as_array()
        .map(|ms| {
            ms.iter()
                .map(|m| m["pbrMetallicRoughness"].get("baseColorFactor").is_some())
                .collect()
        })
        .unwrap_or_default()
}

//! What a frame is traced with: the scene prepared for tracing ([`PreparedScene`]), what one
//! frame of the wall is rendered with ([`FrameView`]), and the rays it traced ([`RayCounts`]).
//! The shading modules and the frame's loop both build on these; this module uses neither.

use crate::bvh::Accel;
use crate::pixel_rays::PixelRays;
use crate::scene::{Light, Material, Scene};
use crate::slot_colors::SlotColors;
use crate::slot_materials::SlotMaterials;
use crate::spheres::SphereAccel;
use crate::volume::PreparedVolume;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use tessera_model::camera::Camera;
use tessera_model::light::Lights;
use tessera_model::params::RenderParams;
use tessera_model::wall::{Tile, WallLayout};
use tessera_protocol::FrameStart;

/// A scene ready to trace: materials and lights from the scene, plus its BVH.
pub struct PreparedScene {
    /// The BVH over the triangles; for a scene in shared memory only its depth (the tree and
    /// triangles are in `shared`).
    pub accel: Accel,
    /// The triangles and their tree in distributed shared memory, when the scene is shared
    /// rather than replicated on every render node.
    pub shared: Option<crate::dsm::DsmTree>,
    /// Material index of each leaf slot.
    pub(crate) slot_material: SlotMaterials,
    /// Texture coordinates and vertex colours of each leaf slot, and the textures; `None`
    /// when every triangle is drawn in its material's colour (always, for a shared scene).
    pub(crate) colors: Option<Box<SlotColors>>,
    pub(crate) materials: Vec<Material>,
    /// Whether any material is transparent: without, the blending path is never entered.
    pub blends: bool,
    pub(crate) lights: Vec<Light>,
    /// Length of the scene's bounding-box diagonal: the scale of offsets and AO reach.
    pub(crate) diagonal: f32,
    /// Particles, if the scene has any.
    pub spheres: Option<SphereAccel>,
    /// Attribute values mapped to the two ends of the colour map.
    pub(crate) attribute_range: (f32, f32),
    /// The scene's volume, bricked, if it has one: for a time series, the step being shown
    /// (see [`PreparedScene::set_volume`]).
    pub volume: Option<Arc<PreparedVolume>>,
}

impl PreparedScene {
    /// Builds the BVH of `scene` and takes its materials, lights, particles and volume.
    pub fn new(scene: &Scene) -> Self {
        Self::from_accel(scene, Accel::build(scene))
    }

    /// Uses an already built (e.g. cached) BVH of `scene`.
    pub fn from_accel(scene: &Scene, accel: Accel) -> Self {
        Self::from_accel_in(scene, accel, scene.bounds(), None)
    }

    /// [`PreparedScene::from_accel`] with the scene's [`Scene::bounds`] measured before its
    /// triangles were freed, and its slots' materials when its scene index was not kept (see
    /// [`crate::bvh::cache::load_lean`]); a scene with texture coordinates or vertex colours
    /// must keep its triangles.
    pub fn from_accel_in(
        scene: &Scene,
        accel: Accel,
        bounds: crate::geometry::Bounds,
        slot_material: Option<Vec<u16>>,
    ) -> Self {
        let slot_material = SlotMaterials::PerSlot(slot_material.unwrap_or_else(|| {
            accel
                .scene_index
                .iter()
                .map(|&i| scene.triangle_material[i as usize])
                .collect()
        }));
        let colors = SlotColors::of(scene, &accel.scene_index).map(Box::new);
        PreparedScene {
            diagonal: bounds.diagonal().length(),
            colors,
            accel,
            shared: None,
            slot_material,
            materials: scene.materials.clone(),
            blends: scene.has_transparency(),
            lights: scene.lights.clone(),
            spheres: SphereAccel::build(&scene.particles),
            attribute_range: scene.attribute_range(),
            volume: scene
                .volume
                .as_ref()
                .map(|v| Arc::new(PreparedVolume::new(v, &scene.render_from_world))),
        }
    }

    /// Frees what only caching and AOVs read, for a render node: the map from leaf slots to
    /// scene triangles (only AOVs' primitive index needs it), 4 bytes a triangle.
    pub fn slim_for_rendering(&mut self) {
        self.accel.scene_index = Vec::new();
    }

    /// Bytes of the per-slot material indices, texture coordinates and vertex colours, and
    /// of the textures (for memory reports).
    pub fn slot_material_bytes(&self) -> usize {
        self.slot_material.bytes() + self.colors.as_ref().map_or(0, |c| c.bytes())
    }

    /// Shows `volume` from now on: a time series' next step, from a [`crate::volume::SeriesCache`].
    pub fn set_volume(&mut self, volume: Arc<PreparedVolume>) {
        self.volume = Some(volume);
    }

    /// Triangles in the scene, wherever they are held.
    pub fn triangle_count(&self) -> usize {
        match &self.shared {
            Some(tree) => tree.layout().triangle_count as usize,
            None => self.accel.triangles.len(),
        }
    }

    /// No triangles, particles or volume: every pixel is the backdrop.
    pub fn is_empty(&self) -> bool {
        self.accel.triangles.is_empty()
            && self.shared.is_none()
            && self.spheres.is_none()
            && self.volume.is_none()
    }

    /// The scene's own lights, in render coordinates (a frame may light it with others: see
    /// [`FrameView::lights`]).
    pub fn lights(&self) -> &[Light] {
        &self.lights
    }

    pub(crate) fn spheres(&self) -> &SphereAccel {
        self.spheres
            .as_ref()
            .expect("a sphere hit implies the scene has spheres")
    }
}

/// What one frame is rendered with.
#[derive(Clone, Debug)]
pub struct FrameView {
    /// The frame's number: it seeds the frame's random samples (jitter, AO directions).
    pub frame: u64,
    /// The rays of the camera's one image (a grid wall's virtual image).
    pub rays: PixelRays,
    /// Each viewport's own rays, for a wall that is not one image (physical screens, stereo);
    /// `None`: every tile takes `rays`.
    pub viewports: Option<Arc<[PixelRays]>>,
    /// The frame's render parameters (shading, samples, cutting planes, volume settings).
    pub params: RenderParams,
    /// Lights in place of the scene's own, if the frame's state has some.
    pub lights: Option<Lights>,
}

impl FrameView {
    /// Frame `frame` seen by `camera` with `params` and the scene's own lights.
    pub fn new(
        frame: u64,
        camera: &Camera,
        params: RenderParams,
        wall_width: u32,
        wall_height: u32,
    ) -> Self {
        FrameView {
            frame,
            rays: PixelRays::new(camera, wall_width, wall_height),
            viewports: None,
            params,
            lights: None,
        }
    }

    /// Frame `frame` of `wall` seen by `camera` with `params`: one frustum for a grid wall's
    /// one image, else one a viewport (see `views`).
    pub fn for_wall(frame: u64, camera: &Camera, params: RenderParams, wall: &WallLayout) -> Self {
        let (w, h) = wall.image_size().unwrap_or((wall.width(), wall.height()));
        FrameView {
            viewports: crate::views::viewport_rays(camera, wall),
            ..Self::new(frame, camera, params, w, h)
        }
    }

    /// What a frame start says to render, on `wall`.
    pub fn of_start(start: &FrameStart, wall: &WallLayout) -> Self {
        FrameView {
            lights: start.lights,
            ..Self::for_wall(start.frame.0, &start.camera, start.params, wall)
        }
    }

    /// The rays of `tile`'s viewport.
    #[inline]
    pub fn rays_for(&self, tile: &Tile) -> &PixelRays {
        match &self.viewports {
            Some(v) => &v[tile.viewport as usize],
            None => &self.rays,
        }
    }

    /// The lights this frame is lit by: its state's, or else the scene's.
    #[inline]
    pub fn lights<'a>(&'a self, scene: &'a PreparedScene) -> &'a [Light] {
        match &self.lights {
            Some(lights) => lights.as_slice(),
            None => &scene.lights,
        }
    }
}

/// Rays traced, by kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RayCounts {
    /// Camera rays, one per pixel sample.
    pub primary: u64,
    /// Rays towards a light, testing whether a surface point is in its shadow.
    pub shadow: u64,
    /// Ambient-occlusion rays.
    pub ambient: u64,
    /// Rays reflected by mirrors.
    pub reflected: u64,
    /// Rays continued through transparent surfaces (each one a blend).
    pub transmitted: u64,
}

impl RayCounts {
    /// Rays of every kind together.
    pub fn total(&self) -> u64 {
        self.primary + self.shadow + self.ambient + self.reflected + self.transmitted
    }

    /// The rays of both, kind by kind.
    pub(crate) fn add(self, other: RayCounts) -> RayCounts {
        RayCounts {
            primary: self.primary + other.primary,
            shadow: self.shadow + other.shadow,
            ambient: self.ambient + other.ambient,
            reflected: self.reflected + other.reflected,
            transmitted: self.transmitted + other.transmitted,
        }
    }
}

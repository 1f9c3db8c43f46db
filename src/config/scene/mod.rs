//! `[scene]`: which scene (`kind`) and its keys, one module per scene kind with the keys' defaults. The
//! scenes themselves (extent, geometry, initial state, observables) are built in `crate::scenes` from these.

mod box_scene;
mod calibration;
mod cavity;
mod channel;
mod collision;
mod couette;
mod drag_array;
mod granular_box;
mod hopper;
mod incline;
mod settling;
mod taylor_green;

pub use box_scene::{BoxConfig, PlaneConfig, SphereConfig};
pub use calibration::CalibrationConfig;
pub use cavity::CavityConfig;
pub use channel::ChannelConfig;
pub use collision::CollisionConfig;
pub use couette::CouetteConfig;
pub use drag_array::DragArrayConfig;
pub use granular_box::GranularBoxConfig;
pub use hopper::HopperConfig;
pub use incline::InclineConfig;
pub use settling::{SettlingSphereConfig, TEN_CATE_BOX, TEN_CATE_DIAMETER, TEN_CATE_START};
pub use taylor_green::TaylorGreenConfig;

use serde::{Deserialize, Serialize};

/// `[scene]`: which scene (`kind`) and its parameters.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SceneConfig {
    /// Force-driven Poiseuille flow between two walls.
    Channel(ChannelConfig),
    /// Shear flow between a resting and a moving wall.
    Couette(CouetteConfig),
    /// Decaying Taylor–Green vortex in a periodic box.
    TaylorGreen(TaylorGreenConfig),
    /// Lid-driven cubic cavity.
    Cavity(CavityConfig),
    /// A box of fluid with optional walls, planes, body force and initial velocity.
    Box(BoxConfig),
    /// Dry granular pile: spheres poured into a closed box settle (fluid off).
    GranularBox(GranularBoxConfig),
    /// One sphere rolling or sliding down an inclined plane (fluid off).
    Incline(InclineConfig),
    /// Head-on and oblique sphere pairs colliding (fluid off).
    Collision(CollisionConfig),
    /// A fixed sphere in a periodic cube driven by a body force: drag of a simple cubic array.
    DragArray(DragArrayConfig),
    /// One sphere settling in a closed box of fluid.
    SettlingSphere(SettlingSphereConfig),
    /// Spheres settling through a hopper narrowed by four inclined planes (section 4.3).
    Hopper(HopperConfig),
    /// The workload-calibration set-up of section 3.3.
    Calibration(CalibrationConfig),
}

/// Default `scene.seed` of the scenes with random placement or jitter.
fn default_seed() -> u64 {
    1
}

/// The scene kinds, for messages.
pub const KINDS: &str = "channel, couette, taylor_green, cavity, box, granular_box, incline, collision, drag_array, settling_sphere, hopper, calibration";

/// Checks a raw `[scene]` table against the keys of its `kind`, so errors name the full key path
/// (`scene.resolution: invalid type ...`); serde's tagged enums would only say `scene`.
pub fn check_table(scene: &toml::Value) -> std::result::Result<(), String> {
    fn de<T: serde::de::DeserializeOwned>(v: toml::Value) -> std::result::Result<(), String> {
        serde_path_to_error::deserialize::<_, T>(v).map(|_| ()).map_err(|e| {
            let p = e.path().to_string();
            let inner = e.inner().to_string().split_whitespace().collect::<Vec<_>>().join(" ");
            if p == "." {
                format!("scene: {inner}")
            } else {
                format!("scene.{p}: {inner}")
            }
        })
    }
    let toml::Value::Table(t) = scene else {
        return Err("scene: must be a table ([scene] with kind = ...)".into());
    };
    let mut t = t.clone();
    let kind = match t.remove("kind") {
        Some(toml::Value::String(k)) => k,
        Some(other) => return Err(format!("scene.kind = {other}: must be a string")),
        None => {
            return Err(format!("scene.kind: missing; one of {KINDS}"));
        }
    };
    let v = toml::Value::Table(t);
    match kind.as_str() {
        "channel" => de::<ChannelConfig>(v),
        "couette" => de::<CouetteConfig>(v),
        "taylor_green" => de::<TaylorGreenConfig>(v),
        "cavity" => de::<CavityConfig>(v),
        "box" => de::<BoxConfig>(v),
        "granular_box" => de::<GranularBoxConfig>(v),
        "incline" => de::<InclineConfig>(v),
        "collision" => de::<CollisionConfig>(v),
        "drag_array" => de::<DragArrayConfig>(v),
        "settling_sphere" => de::<SettlingSphereConfig>(v),
        "hopper" => de::<HopperConfig>(v),
        "calibration" => de::<CalibrationConfig>(v),
        k => Err(format!("scene.kind = {k:?}: unknown scene; one of {KINDS}")),
    }
}

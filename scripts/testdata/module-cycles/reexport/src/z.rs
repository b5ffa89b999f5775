use crate::a::Ay;
use crate::Thing;
pub fn z() -> (Ay, Thing) {
    (Ay, Thing)
}

use crate::b::Bee;
pub struct Ay;
pub fn fa() -> Bee {
    Bee
}

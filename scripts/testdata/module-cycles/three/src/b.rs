pub struct Bee;
pub fn fb() {
    super::c::fc();
}

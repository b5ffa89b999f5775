pub struct Thing;
pub fn g() -> crate::a::Ay {
    crate::a::Ay
}

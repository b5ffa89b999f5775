mod n;
#[macro_export]
macro_rules! shout {
    () => {};
}
pub fn top() {
    n::inner();
}
